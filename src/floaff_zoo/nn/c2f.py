"""C2F-Exp-style coarse-to-fine base placement (training-free; docs/background.md §3), pure torch.

Per round t = 0..T-1: alpha_t = max_alpha * sigmoid(k (t - 0.35 T)), k = 12 / T; candidates are
drawn from the current semantic Gaussian N(mu, sigma^2 I) and kept when they lie ``r_min``-``r_max``
from the affordance point g and on free cells; each gets w = p_geo^alpha * p_sem^(1 - alpha) with
p_geo = exp(-(|c - g| - r*)^2 / (2 sigma_dist^2)) (the ring prior) and
p_sem = exp(-|c - mu|^2 / (2 sigma^2)); a scorer (GPT-4o in C2F-Exp, pluggable here) picks the
top ``top_k``; mu moves to their mean (drift capped at ``max_drift`` from mu_0) and sigma shrinks by
``sigma_decay``.
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from floaff_zoo.nn.placement import heading_to, occupied_cells

#: scorer(candidates [n, 2], weights [n], context) -> scores [n] (higher = better); the context holds ``cells``
#: [K, 2] (occupied cell centres), ``g`` [2] (the target), ``target_yaw``, ``round`` (0 .. rounds; ``rounds`` in the
#: final pose), ``mu`` [2], ``sigma`` and ``alpha`` (this round's Gaussian and its geometric share), in every round
#: and in the final pose
Scorer = Callable[[Tensor, Tensor, dict[str, Any]], Tensor]


def geometric_scorer(candidates: Tensor, weights: Tensor, context: dict[str, Any]) -> Tensor:
    """Default deterministic scorer: the C2F-Exp weight itself (geometric prior x semantic Gaussian)."""
    return weights


def clearance_scorer(candidates: Tensor, weights: Tensor, context: dict[str, Any]) -> Tensor:
    """Weight times a soft clearance bonus (prefers candidates far from obstacles)."""
    cells = context["cells"]
    if cells.numel() == 0:
        return weights
    d = torch.cdist(candidates, cells).amin(dim=1)
    return weights * (1 - torch.exp(-d / 0.3))


SCORERS: dict[str, Scorer] = {"geometric": geometric_scorer, "clearance": clearance_scorer}


def resolve_scorer(name: str) -> Scorer:
    """A registered scorer name or ``"package.module:function"``."""
    if name in SCORERS:
        return SCORERS[name]
    if ":" in name:
        mod, fn = name.split(":", 1)
        try:
            return getattr(importlib.import_module(mod), fn)
        except (ImportError, AttributeError) as exc:
            raise ValueError(f"C2F-Exp scorer {name!r} cannot be imported: {exc}") from exc
    raise ValueError(f"unknown C2F-Exp scorer {name!r}; choose {sorted(SCORERS)} or 'module:function'")


@dataclass
class C2FConfig:
    """Parameters of the coarse-to-fine search (defaults: C2F-Exp paper/code)."""

    r_star: float = 0.7
    sigma_dist: float = 0.1
    sigma_bias: float = 0.2
    sigma_decay: float = 0.8
    rounds: int = 3
    candidates: int = 20
    top_k: int = 3
    r_min: float = 0.4
    r_max: float = 1.2
    max_alpha: float = 0.5
    max_drift: float = 1.2
    cell: float = 0.05
    z_min: float = 0.05
    clearance: float = 0.25
    seed: int = 0


def alpha_schedule(t: float, rounds: int, max_alpha: float) -> float:
    """alpha_t = max_alpha * sigmoid(12 / T * (t - 0.35 T))."""
    k = 12.0 / rounds
    return max_alpha / (1.0 + math.exp(-k * (t - 0.35 * rounds)))


class C2FPlanner(torch.nn.Module):
    """Parameter-free coarse-to-fine planner producing per-floor-point scores and a base pose."""

    def __init__(self, config: C2FConfig, scorer: Scorer) -> None:
        super().__init__()
        self.cfg = config
        self.scorer = scorer

    def weight(self, xy: Tensor, g: Tensor, mu: Tensor, sigma: float, alpha: float) -> Tensor:
        """w = p_geo^alpha * p_sem^(1 - alpha) at points xy [n, 2]."""
        c = self.cfg
        d = (xy - g).norm(dim=-1)
        log_geo = -((d - c.r_star) ** 2) / (2 * c.sigma_dist**2)
        log_sem = -((xy - mu) ** 2).sum(-1) / (2 * sigma**2)
        return torch.exp(alpha * log_geo + (1 - alpha) * log_sem)

    def free(self, xy: Tensor, cells: Tensor) -> Tensor:
        """[n] bool: no occupied cell centre within ``clearance`` of the point."""
        if cells.numel() == 0:
            return torch.ones(xy.shape[0], dtype=torch.bool, device=xy.device)
        return torch.cdist(xy, cells).amin(dim=1) > self.cfg.clearance

    def _candidates(self, g: Tensor, mu: Tensor, sigma: float, cells: Tensor, gen: torch.Generator) -> Tensor:
        c = self.cfg
        pts = mu + sigma * torch.randn(c.candidates * 10, 2, generator=gen)
        # ring samples keep the search alive when the Gaussian sits on obstacles
        ang = torch.rand(c.candidates * 10, generator=gen) * 2 * math.pi
        rad = c.r_min + (c.r_max - c.r_min) * torch.rand(c.candidates * 10, generator=gen)
        ring = g + torch.stack([rad * torch.cos(ang), rad * torch.sin(ang)], dim=-1)
        pts = torch.cat([pts, ring])
        d = (pts - g).norm(dim=-1)
        ok = (d >= c.r_min) & (d <= c.r_max) & self.free(pts, cells)
        return pts[ok][: c.candidates]

    @torch.no_grad()
    def search(self, scene_xyz: Tensor, scene_mask: Tensor, target_xyz: Tensor, target_yaw: Tensor) -> dict[str, Any]:
        """Run the T rounds for one sample (CPU float32).

        Returns:
            dict with g [2], mu [2], sigma, alpha (final), cells [K, 2], history (list of mu), gen (the search's
            generator) and target_yaw (the final pose's scorer gets the search rounds' keys).
        """
        c = self.cfg
        gen = torch.Generator().manual_seed(int(c.seed))
        cells = occupied_cells(scene_xyz, scene_mask, c.cell, c.z_min)
        g = target_xyz[:2]
        yaw = float(target_yaw)
        # the VLM's "A" arrow is replaced by the target's front normal
        mu0 = g + c.r_star * torch.tensor([math.cos(yaw), math.sin(yaw)])
        mu, sigma = mu0.clone(), c.sigma_bias
        context: dict[str, Any] = {"cells": cells, "g": g, "target_yaw": yaw}
        history = [mu.clone()]
        for t in range(c.rounds):
            alpha = alpha_schedule(t, c.rounds, c.max_alpha)
            cand = self._candidates(g, mu, sigma, cells, gen)
            if cand.shape[0] > 0:
                w = self.weight(cand, g, mu, sigma, alpha)
                scores = self.scorer(cand, w, {**context, "round": t, "mu": mu, "sigma": sigma, "alpha": alpha})
                top = scores.topk(min(c.top_k, cand.shape[0])).indices
                new = cand[top].mean(dim=0)
                drift = new - mu0
                if drift.norm() > c.max_drift:
                    new = mu0 + drift * (c.max_drift / drift.norm())
                mu = new
            sigma *= c.sigma_decay
            history.append(mu.clone())
        alpha = alpha_schedule(c.rounds, c.rounds, c.max_alpha)
        return {
            "g": g,
            "mu": mu,
            "sigma": sigma,
            "alpha": alpha,
            "cells": cells,
            "history": history,
            "gen": gen,
            "target_yaw": yaw,
        }

    @torch.no_grad()
    def score_floor(self, state: dict[str, Any], floor_xyz: Tensor, floor_mask: Tensor) -> Tensor:
        """Final weight at the floor points, zero off the 0.4-1.2 m band and on occupied cells,
        divided by its max -> [M] in [0, 1]."""
        c = self.cfg
        xy = floor_xyz[:, :2]
        w = self.weight(xy, state["g"], state["mu"], state["sigma"], state["alpha"])
        d = (xy - state["g"]).norm(dim=-1)
        w = w * ((d >= c.r_min) & (d <= c.r_max) & self.free(xy, state["cells"]) & floor_mask).float()
        top = w.max()
        return w / top if top > 0 else w

    @torch.no_grad()
    def final_pose(self, state: dict[str, Any]) -> tuple[float, float, float]:
        """C2F-Exp's last step: 20 candidates -> scorer keeps 5 -> drop the 2 farthest from their
        mean -> average 3; if that point is not free, the nearest kept candidate. Yaw faces g."""
        c = self.cfg
        g, mu, sigma, alpha = state["g"], state["mu"], state["sigma"], state["alpha"]
        cand = self._candidates(g, mu, sigma, state["cells"], state["gen"])
        if cand.shape[0] == 0:
            best = mu
        else:
            w = self.weight(cand, g, mu, sigma, alpha)
            # the keys of every search round (a plugged-in scorer read target_yaw there, then failed here)
            context = {"cells": state["cells"], "g": g, "target_yaw": state["target_yaw"], "round": c.rounds}
            context.update(mu=mu, sigma=sigma, alpha=alpha)
            scores = self.scorer(cand, w, context)
            keep = cand[scores.topk(min(5, cand.shape[0])).indices]
            if keep.shape[0] > 3:
                m = keep.mean(dim=0)
                keep = keep[(keep - m).norm(dim=-1).argsort()[:3]]
            best = keep.mean(dim=0)
            if not bool(self.free(best[None], state["cells"])[0]):
                best = keep[(keep - best).norm(dim=-1).argmin()]
        yaw = float(heading_to(best, g))
        return float(best[0]), float(best[1]), yaw
