"""FloAffDataModule: the base LightningDataModule (splits, loaders, collate, transforms)."""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator, Mapping, Sequence
from functools import partial
from typing import Any, Literal

import lightning as L
import numpy as np
import torch
from lightning.pytorch.trainer.states import TrainerFn
from lightning.pytorch.utilities import rank_zero_warn
from lightning.pytorch.utilities.exceptions import MisconfigurationException
from torch.utils.data import DataLoader, Dataset, RandomSampler

from floaff_zoo import checks
from floaff_zoo.checks import check_integer, is_number, shown
from floaff_zoo.contract import Sample, collate_samples, validate_sample
from floaff_zoo.data.transforms import SampleTransform, apply_transforms

Split = Literal["train", "val", "test", "predict"]
#: seed stream of each split's eval transforms and resampling; predict reads the test split in every DataModule of the
#: zoo, so it shares test's stream: ``floaff-zoo predict`` writes the maps of the very inputs ``test`` scored
_SPLIT_OFFSET = {"train": 0, "val": 1, "test": 2, "predict": 2}


class DataConfigError(MisconfigurationException, ValueError):
    """A DataModule argument out of range; the message names ``data.<field>`` and the value.

    A ValueError for Python callers and a MisconfigurationException, which ``floaff-zoo`` prints as one line.
    """


def check_size(field: str, value: Any, minimum: int, none_means: str | None = None) -> None:
    """Raise DataConfigError unless ``value`` is an int >= ``minimum`` (or None where ``none_means`` says what
    None does); ``field`` is the DataModule argument's name."""
    check_integer(f"data.{field}", value, minimum, error=DataConfigError, none_means=none_means)


def check_flag(field: str, value: Any) -> None:
    """``checks.check_flag`` of ``data.<field>`` as a DataConfigError."""
    checks.check_flag(f"data.{field}", value, error=DataConfigError)


def check_fraction(field: str, value: Any) -> None:
    """DataConfigError unless ``value`` is a number in [0, 1): a text failed in a bare comparison, False was taken
    as 0."""
    if not (is_number(value) and 0 <= value < 1):
        raise DataConfigError(f"data.{field} must be in [0, 1), got {shown(value)}")


def check_choice(field: str, value: Any, choices: tuple[str, ...]) -> None:
    """DataConfigError unless ``value`` is one of ``choices``."""
    if not (isinstance(value, str) and value in choices):
        raise DataConfigError(f"data.{field} must be one of {', '.join(map(repr, choices))}, got {value!r}")


def check_transforms(field: str, value: Any) -> list[SampleTransform]:
    """``value`` (None = none) as a list; DataConfigError naming ``data.<field>`` and the position of an entry that is
    not a :class:`SampleTransform` (a text or a dict failed only at the first sample: "'str' object is not
    callable"), or when ``value`` is no list (a single transform, a text: its letters were taken as the entries)."""
    if value is None:
        return []
    if isinstance(value, (str, bytes, Mapping)) or not isinstance(value, Sequence):
        raise DataConfigError(f"data.{field} must be a list of transforms, got {value!r}")
    for i, t in enumerate(value):
        if not isinstance(t, SampleTransform):
            raise DataConfigError(
                f"data.{field}[{i}] must be a SampleTransform (class_path and init_args in a config), got {t!r}"
            )
    return list(value)


def after_base_seed(state: torch.Tensor) -> torch.Tensor:
    """A generator's state after a loader iterator drew its workers' base seed from ``state``, as torch's
    ``_BaseDataLoaderIter`` draws it (one int64): where the next epoch's permutation is drawn from."""
    gen = torch.Generator()
    gen.set_state(state)
    torch.empty((), dtype=torch.int64).random_(generator=gen)
    return gen.get_state()


class EpochSampler(RandomSampler):
    """The train loader's shuffle: ``RandomSampler`` on the loader's generator, drawing each epoch's permutation exactly
    as it does, that also keeps the generator state the running epoch's permutation was drawn from.

    :meth:`resume_at` pins the permutation a resumed fit's first epoch draws, whatever Lightning does before it: a fit
    resumed from a checkpoint written mid-epoch (``val_check_interval``, ``max_steps``) is restarted with a new loader
    iterator from which Lightning takes the epoch's remaining batch count, which were the first batches of a new
    permutation (samples of the epoch trained twice, others not at all); one resumed from the validation at an
    epoch's last batch makes two iterators (with workers, both draw from the sampler), and the second one's seed
    draw moved every later permutation. A ``RandomSampler`` still, so under DDP Lightning replaces it by its
    ``DistributedSampler`` as before.
    """

    def __init__(self, data_source: Dataset, generator: torch.Generator) -> None:
        super().__init__(data_source, generator=generator)  # type: ignore[arg-type]
        self.shuffle_generator = generator
        #: the generator state the running epoch's permutation was drawn from (None before the first epoch)
        self.epoch_state: torch.Tensor | None = None
        self._resume: tuple[torch.Tensor, int] | None = None

    def resume_at(self, epoch_state: torch.Tensor, samples_done: int) -> None:
        """Make every epoch started until :meth:`resumed` the permutation drawn from ``epoch_state``, past its first
        ``samples_done`` samples (Lightning may start, and drop, iterators before the resumed fit trains)."""
        self._resume = (epoch_state, samples_done)

    def resumed(self) -> None:
        """The resumed fit trains: later epochs draw on from the generator."""
        self._resume = None

    @property
    def pinned(self) -> tuple[torch.Tensor, int] | None:
        """``(epoch_state, samples_done)`` given to :meth:`resume_at` while the resumed fit has trained nothing yet."""
        return self._resume

    def __iter__(self) -> Iterator[int]:
        skip = 0
        if self._resume is not None:
            state, skip = self._resume
            self.shuffle_generator.set_state(state)
        self.epoch_state = self.shuffle_generator.get_state()
        return itertools.islice(super().__iter__(), skip, None)


class TransformedDataset(Dataset):
    """A split's dataset seen through the DataModule's per-sample transforms and hook.

    Training draws a fresh generator per access (from torch's global RNG, which Lightning seeds and
    re-seeds per worker); evaluation uses one generator per (seed, split, index) so metrics repeat.
    """

    def __init__(
        self,
        dataset: Dataset,
        transforms: Sequence[SampleTransform],
        hook: Callable[[Sample, str], Sample] | None,
        split: str,
        seed: int,
    ) -> None:
        self.dataset, self.transforms, self.hook, self.split, self.seed = dataset, list(transforms), hook, split, seed

    def __len__(self) -> int:
        return len(self.dataset)  # type: ignore[arg-type]

    def __getitem__(self, i: int) -> Sample:
        s = self.dataset[i]
        if not self.transforms and self.hook is None:
            return s
        if "scene_mask" not in s or "floor_mask" not in s or not torch.is_tensor(s["scene_xyz"]):
            s = validate_sample(s)
        if self.split == "train":
            rng = np.random.default_rng(int(torch.randint(0, 2**62, (1,)).item()))
        else:
            rng = np.random.default_rng([self.seed, _SPLIT_OFFSET.get(self.split, 9), i])
        s = apply_transforms(s, self.transforms, rng)
        return self.hook(s, self.split) if self.hook is not None else s


class FloAffDataModule(L.LightningDataModule):
    """The data: any data module of the zoo; --data.help CLASS lists one's arguments

    The parent of every data module: ``setup`` fills ``self.datasets[split]``; loaders collate to fixed sizes. (The
    first line is the title of the --data group in ``floaff-zoo fit --help``.)

    Args:
        batch_size: samples per batch, >= 1 (eval loaders use ``eval_batch_size`` when set).
        eval_batch_size: batch size of val/test/predict loaders, >= 1 (``None`` = ``batch_size``; MoMa-Kitchen's
            official code uses 64).
        num_workers: DataLoader workers, >= 0.
        num_points: scene points per sample after collation, >= 1 (``None`` = largest in the batch).
        num_floor: floor points per sample after collation, >= 1 (``None`` = largest in the batch).
        collate_mode: ``resample`` (fast mode: exactly ``num_points`` valid points; with ``num_points`` None, the
            batch's largest cloud, every other one filled up by repeats, so an eval sample's points depend on its
            batch) or ``pad`` (faithful mode: truncate/zero-pad with masks).
        seed: seed of the splits, the train shuffle and the evaluation splits' resampling and transforms (train
            resampling and augmentation draw from torch's global generator: ``seed_everything`` fixes them).
        train_transforms: per-sample transforms of the train split, in order (e.g.
            ``YawPerturb``, ``Jitter``; any :class:`~floaff_zoo.data.transforms.SampleTransform`
            subclass by ``class_path``).
        eval_transforms: per-sample transforms of val/test/predict (seeded per sample index).
        persistent_train_workers: keep the train loader's workers from one epoch to the next. By default they are
            started anew every epoch, so that a fit resumed from a checkpoint draws the same worker seeds (the same
            augmentation noise) as an uninterrupted one; the restart is cheap under Linux's ``fork`` but re-imports
            the package in every worker and epoch under ``spawn`` (macOS, Windows), longer than a CPU training epoch
            (``docs/performance.md``). With True a resumed fit is not the uninterrupted one (other worker seeds, so
            other augmentation noise, and the shuffle stream one draw apart; warned). The eval loaders always keep
            theirs.

    Subclasses (or a method's code) may override :meth:`sample_transform`, a hook applied to every
    sample after the configured transforms. A subclass configured to train without any validation split sets
    ``validates`` False: ``fit`` then monitors no checkpoint metric and refuses a scheduler that follows one.
    """

    validates: bool = True

    def __init__(
        self,
        batch_size: int = 8,
        eval_batch_size: int | None = None,
        num_workers: int = 0,
        num_points: int | None = 4096,
        num_floor: int | None = None,
        collate_mode: Literal["pad", "resample"] = "resample",
        seed: int = 0,
        train_transforms: list[SampleTransform] | None = None,
        eval_transforms: list[SampleTransform] | None = None,
        persistent_train_workers: bool = False,
    ) -> None:
        super().__init__()
        if type(self) is FloAffDataModule:  # a data config without class_path builds the base, which reads nothing
            raise DataConfigError(
                "data: no class_path: FloAffDataModule is the base class and has no data; set data.class_path "
                "(e.g. floaff_zoo.data.floaff_kitchen.FloAffKitchenDataModule, or a configs/data/*.yaml first)"
            )
        # checked here: a bad size otherwise fails inside the first batch (torch.zeros, DataLoader) naming no field
        check_size("batch_size", batch_size, 1)
        check_size("eval_batch_size", eval_batch_size, 1, "use batch_size")
        check_size("num_workers", num_workers, 0)
        check_size("num_points", num_points, 1, "the largest cloud in the batch")
        check_size("num_floor", num_floor, 1, "the largest floor in the batch")
        # numpy's seeded streams refuse a negative seed only at setup, per sample; the loaders' torch generators one
        # past 64 bits at the first batch
        check_integer("data.seed", seed, 0, 2**64 - 1, error=DataConfigError)
        if collate_mode not in ("pad", "resample"):
            raise DataConfigError(f"data.collate_mode must be 'pad' or 'resample', got {collate_mode!r}")
        check_flag("persistent_train_workers", persistent_train_workers)
        self.train_transforms = check_transforms("train_transforms", train_transforms)
        self.eval_transforms = check_transforms("eval_transforms", eval_transforms)
        # Python ints: numpy's pass the checks, but DataLoader and torch's manual_seed refused them at the first batch
        self.batch_size = int(batch_size)
        self.eval_batch_size = self.batch_size if eval_batch_size is None else int(eval_batch_size)
        self.num_workers = int(num_workers)
        self.persistent_train_workers = persistent_train_workers
        self.num_points = None if num_points is None else int(num_points)
        self.num_floor = None if num_floor is None else int(num_floor)
        self.collate_mode = collate_mode
        self.seed = int(seed)
        self.datasets: dict[str, Dataset] = {}
        #: split -> keys of the samples that failed at load time after setup and were replaced (``meta['replaces']``)
        self.load_failures: dict[str, set[str]] = {}
        #: the train loader's shuffle generator, and a state a resumed fit's checkpoint gave it before it was made
        self._train_generator: torch.Generator | None = None
        self._train_generator_state: torch.Tensor | None = None
        #: the train loader's sampler, and where a resumed fit's checkpoint stood in an epoch (``_epoch_position``)
        self._train_sampler: EpochSampler | None = None
        self._train_epoch_position: dict[str, Any] | None = None

    def state_dict(self) -> dict[str, Any]:
        """Saved in every checkpoint: the train shuffle's generator state, so a resumed fit goes on with the next
        epochs' orders instead of drawing the first epoch's again, and, written mid-epoch, where the fit stood in the
        running epoch's permutation (``train_epoch``), so it trains the rest of that permutation first."""
        gen = self._train_generator
        if gen is None:
            return {}
        position = self._epoch_position()
        return {"train_generator": gen.get_state(), **({"train_epoch": position} if position else {})}

    def _epoch_position(self) -> dict[str, Any] | None:
        """``{"generator": state, "samples_done": n, "size": split size}``: the generator state the permutation a fit
        resumed from this checkpoint trains next is drawn from, and how many of its samples were trained (those of
        the running epoch, or 0 at an epoch's end: the next epoch's); None outside a fit, before the first batch of an
        epoch, or when the loader trains with another sampler (DDP's)."""
        sampler, gen, trainer = self._train_sampler, self._train_generator, self.trainer
        if sampler is not None and sampler.pinned is not None:
            # nothing trained since the checkpoint the fit resumed from: its position stands (Lightning writes
            # last.ckpt again at that step before training, and a kill then lost the position)
            state, done = sampler.pinned
            return {"generator": state, "samples_done": done, "size": len(sampler.data_source)}  # type: ignore[arg-type]
        if sampler is None or sampler.epoch_state is None or gen is None:
            return None
        if trainer is None or trainer.state.fn != TrainerFn.FITTING:
            return None
        done = trainer.fit_loop.epoch_loop.batch_progress.current.ready  # the batches this epoch handed to training
        size = len(sampler.data_source)  # type: ignore[arg-type]
        if 0 < done < trainer.num_training_batches:
            return {"generator": sampler.epoch_state, "samples_done": min(done * self.batch_size, size), "size": size}
        if done == 0:
            return None
        return {"generator": after_base_seed(gen.get_state()), "samples_done": 0, "size": size}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        """A resumed fit's saved state (applied when the train loader is made, after Lightning restores it)."""
        state = state_dict.get("train_generator")
        self._train_generator_state = state if isinstance(state, torch.Tensor) else None
        if self._train_generator is not None and self._train_generator_state is not None:
            self._train_generator.set_state(self._train_generator_state)
        position = state_dict.get("train_epoch")
        self._train_epoch_position = position if isinstance(position, dict) else None
        if self.persistent_train_workers and self.num_workers > 0 and self._train_generator_state is not None:
            rank_zero_warn(
                f"{type(self).__name__}: persistent_train_workers: the resumed fit's loader workers draw their seeds "
                "once, at its start, not where the interrupted fit stood: other augmentation noise and other sample "
                "orders than an uninterrupted fit, from its first epoch (set it false for an exact resume)"
            )

    def collate_fn(self, split: str) -> Callable[[Sequence[Sample]], dict[str, Any]]:
        # eval splits resample each sample from its own seeded stream, so metrics repeat across epochs and worker
        # counts; train draws fresh points
        offsets = {split: _SPLIT_OFFSET[split] for split in ("val", "test", "predict")}
        return partial(
            collate_samples,
            num_points=self.num_points,
            num_floor=self.num_floor,
            mode=self.collate_mode,
            seed=self.seed * 10 + offsets[split] if split in offsets else None,
        )

    def sample_transform(self, sample: Sample, split: str) -> Sample:
        """Hook applied to every sample after the configured transforms (default: identity)."""
        return sample

    def transforms_for(self, split: str) -> list[SampleTransform]:
        """The configured transform list of ``split``."""
        return self.train_transforms if split == "train" else self.eval_transforms

    def skip_log(self, split: str) -> Any:
        """The ``readers.SkipLog`` of what setup skipped for ``split`` (test reports record it), None when the data
        module keeps none (the synthetic data skips nothing)."""
        return None

    def _has_hook(self) -> bool:
        return type(self).sample_transform is not FloAffDataModule.sample_transform

    def _dataloader(self, split: str) -> DataLoader:
        ds = self.datasets.get(split)
        if ds is None:
            raise MisconfigurationException(
                f"{type(self).__name__}: no '{split}' split was set up (available: {sorted(self.datasets)})"
            )
        if len(ds) == 0:
            raise MisconfigurationException(f"{type(self).__name__}: the '{split}' split is empty")
        transforms = self.transforms_for(split)
        if transforms or self._has_hook():
            ds = TransformedDataset(
                ds, transforms, self.sample_transform if self._has_hook() else None, split, self.seed
            )
        # every loader has its own generator: an iterator of a loader without one draws its base seed from torch's
        # global generator, so each validation moved the stream the training augmentation draws from
        generator = torch.Generator().manual_seed(self.seed)
        if split == "train":
            if self._train_generator is not None:  # reloaded in the same fit: go on with its stream, not seed again
                generator = self._train_generator
            elif self._train_generator_state is not None:  # a resumed fit's first train loader
                generator.set_state(self._train_generator_state)
            self._train_generator, self._train_generator_state = generator, None
            sampler = EpochSampler(ds, generator)
            position, self._train_epoch_position = self._train_epoch_position, None
            # a split of another size (other data) has another permutation: its epoch starts afresh
            if position is not None and position.get("size") == len(ds) and torch.is_tensor(position.get("generator")):
                sampler.resume_at(position["generator"], int(position["samples_done"]))
            self._train_sampler = sampler
        # train workers are started anew every epoch (unless persistent_train_workers): their seeds then come from the
        # shuffle generator at each epoch's start, which a checkpoint restores; persistent ones take them once per fit,
        # so a fit resumed with them draws other seeds (other noise) and, one draw later in the stream, other orders
        return DataLoader(
            ds,
            batch_size=self.batch_size if split == "train" else self.eval_batch_size,
            sampler=self._train_sampler if split == "train" else None,  # the shuffle of shuffle=True, resumable
            num_workers=self.num_workers,
            # eval streams are seeded per sample
            persistent_workers=self.num_workers > 0 and (split != "train" or self.persistent_train_workers),
            collate_fn=self.collate_fn(split),
            generator=generator,
        )

    def on_after_batch_transfer(self, batch: Any, dataloader_idx: int) -> Any:
        """Count the samples a dataset replaced because they failed at load time (files changed after setup):
        in the main process, as loader workers keep their own counters. A training batch also ends the pinned
        permutation of a resumed fit (:meth:`EpochSampler.resume_at`)."""
        if self._train_sampler is not None and self._running_split() == "train":
            self._train_sampler.resumed()
        metas = batch.get("meta") if isinstance(batch, dict) else None
        replaced = [str(m["replaces"]) for m in metas or [] if isinstance(m, dict) and m.get("replaces")]
        if replaced:
            self.load_failures.setdefault(self._running_split(), set()).update(replaced)
        return batch

    def _running_split(self) -> str:
        """The split the trainer is iterating (``train``, ``val``, ``test``, ``predict``)."""
        stage = getattr(getattr(self.trainer, "state", None), "stage", None)
        name = str(getattr(stage, "value", stage) or "unknown")  # RunningStage: train, validate, test, ...
        return {"validate": "val", "sanity_check": "val"}.get(name, name)

    def teardown(self, stage: str) -> None:
        """Summarise the load-time replacements of the run (the dataset prints only the first three)."""
        for split, keys in sorted(self.load_failures.items()):
            shown = ", ".join(sorted(keys)[:5]) + (", ..." if len(keys) > 5 else "")
            print(
                f"{type(self).__name__}: {len(keys)} {split} sample(s) failed at load time and were replaced by "
                f"the next sample (metrics count every sample once): {shown}"
            )
        self.load_failures = {}

    def train_dataloader(self) -> DataLoader:
        return self._dataloader("train")

    def val_dataloader(self) -> DataLoader:
        return self._dataloader("val")

    def test_dataloader(self) -> DataLoader:
        return self._dataloader("test")

    def predict_dataloader(self) -> DataLoader:
        return self._dataloader("predict" if "predict" in self.datasets else "test")
