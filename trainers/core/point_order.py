"""The environment's order of candidate points, restored after a half turn of the field.

The environment lists each enemy's ``k`` candidate points by their angle around the enemy,
counter-clockwise from +x in ``[0, 2π)``, and with fewer than ``k`` distinct points repeats
the last one (``server/task/candidates.py``); the abstract action ``(enemy j, choice c)``
drives to the point in slot ``c``. A half turn of the scene adds π to every angle, so the
turned points are no longer in that order: read as they are, the turned episode would hold
point lists the environment never produces. :class:`PointOrder` re-lists each step's points
as the environment lists them in the turned scene, moves the columns that describe each
point with them (the observation's ``(x, y)`` and the ``relative`` features' per-point
block) and relabels the actions and the available actions to match, so that a turned
episode is one the environment could have played.

Angles are compared in the observation's normalised coordinates: they scale x and y by
positive factors, which keeps every point's quadrant and the order of the angles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import torch

from neuronsmae.protocol.env_info import EnvInfo
from neuronsmae.trainers.core.features import Relative


@dataclass(frozen=True)
class PointOrder:
    """Re-lists candidate points in the environment's order, for a task with the points in
    its observation (``info.obs.k > 0``); the agent inputs are the observation, or the
    ``relative`` features of it when ``relative`` is given."""

    info: EnvInfo
    relative: Relative | None = None

    @cached_property
    def _columns(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Columns of each enemy's ``(x, y)`` ``[E, 2]``, of each of its points' ``(x, y)``
        ``[E, k, 2]``, and of everything describing each point ``[E, k, C]``."""
        obs, n_enemies = self.info.obs, self.info.n_enemies
        enemy = [list(obs.pose(obs.enemy(j))[:2]) for j in range(n_enemies)]
        points = [[list(obs.point(j, q)) for q in range(obs.k)] for j in range(n_enemies)]
        moved = torch.tensor(points)
        if self.relative is not None:
            rel = [[list(self.relative.point_columns(j, q)) for q in range(obs.k)]
                   for j in range(n_enemies)]  # fmt: skip
            moved = torch.cat([moved, torch.tensor(rel)], dim=-1)
        return torch.tensor(enemy), torch.tensor(points), moved

    def order(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``obs [..., W]`` → for each slot of the environment's list, the slot of ``obs``
        whose point goes there ``[..., E, k]``; and how many distinct points each enemy
        has ``[..., E, 1]`` (the slots from there on repeat the last)."""
        enemy_cols, point_cols, _ = self._columns
        points = obs[..., point_cols]  # [..., E, k, 2]
        side = points - obs[..., enemy_cols].unsqueeze(-2)
        angle = torch.remainder(torch.atan2(side[..., 1], side[..., 0]), 2 * math.pi)
        repeat = torch.zeros_like(angle, dtype=torch.bool)  # a copy of the previous point
        repeat[..., 1:] = (points[..., 1:, :] == points[..., :-1, :]).all(-1)
        by_angle = torch.argsort(angle.masked_fill(repeat, math.inf), dim=-1, stable=True)
        distinct = (~repeat).sum(-1, keepdim=True)  # ≥ 1: slot 0 is never a repeat
        last = by_angle.gather(-1, distinct - 1)
        slots = torch.arange(angle.shape[-1])
        return torch.where(slots < distinct, by_angle, last), distinct

    def relist(
        self, obs: torch.Tensor, avail: torch.Tensor, actions: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``obs [B, T+1, n, W]``, ``avail [B, T+1, n, A]`` and ``actions [B, T, n]`` with
        every step's points in the environment's order (actions relabelled only for the
        abstract action space, whose choices are the points)."""
        order, distinct = self.order(obs)  # [B, T+1, n, E, k], [B, T+1, n, E, 1]
        _, _, moved = self._columns  # [E, k, C]
        lead = order.shape[:-2]
        width = moved.shape[-1]
        source = moved.expand(*lead, *moved.shape).gather(
            -2, order.unsqueeze(-1).expand(*order.shape, width)
        )
        index = torch.arange(obs.shape[-1]).expand_as(obs).clone()
        index.scatter_(-1, moved.flatten().expand(*lead, -1), source.flatten(-3))
        obs = obs.gather(-1, index)
        if self.info.action_space != "abstract":
            return obs, avail, actions
        k = order.shape[-1]
        base = (torch.arange(order.shape[-2]) * k).unsqueeze(-1)  # [E, 1]: enemy j's first
        slots = torch.arange(k).expand_as(order)
        listed = slots < distinct  # [..., E, k]: new slots that are not repeats
        # A listed slot's availability moves with its point; a repeat keeps its own (the
        # same as a listed one's, but for a destroyed robot's lone no-op, action 0).
        avail = avail.gather(-1, (base + torch.where(listed, order, slots)).flatten(-2))
        # Old slot c goes where its point now stands; a repeat (c ≥ distinct) is a copy of
        # the last distinct point, and goes where that point stands.
        where = torch.zeros(*order.shape[:-1], k + 1, dtype=torch.int64)  # slot k: repeats
        where.scatter_(-1, torch.where(listed, order, k), slots)
        new_slot = where.gather(-1, torch.minimum(slots, distinct - 1))  # [..., E, k_old]
        relabel = (base + new_slot).flatten(-2)  # [B, T+1, n, A]
        actions = relabel[:, :-1].gather(-1, actions.unsqueeze(-1)).squeeze(-1)
        return obs, avail, actions
