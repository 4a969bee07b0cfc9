"""Command-line model specs of the scripts (predict.named_models)."""

import pytest


def test_named_models_reads_name_model_specs(tmp_path):
    from floaff_zoo.predict import named_models

    odd = tmp_path / "epoch=1.ckpt"
    odd.write_bytes(b"")
    got = named_models(["occ=a.ckpt", "hub.name", "occ=b.ckpt", "runs/x/epoch=1-step=9.ckpt", str(odd)])
    assert got == {
        "occ": ["a.ckpt", "b.ckpt"],
        "hub.name": ["hub.name"],
        "runs/x/epoch=1-step=9.ckpt": ["runs/x/epoch=1-step=9.ckpt"],
        str(odd): [str(odd)],
    }
    for bad in ("=a.ckpt", "occ="):
        with pytest.raises(ValueError, match="bad model argument"):
            named_models([bad])
