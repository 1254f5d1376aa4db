"""Social-force walkers, alone and in groups of two or three.

The force model of Helbing & Molnár (1995) with the body forces of Helbing, Farkas & Vicsek
(2000) and the group cohesion of Moussaïd et al. (2010), per unit mass, vectorised over people.
Person ``i`` (radius ``r``, velocity ``v_i``, preferred speed ``v0_i``, heading for its next
waypoint along the unit vector ``e_i``) accelerates by

    dv_i/dt = (v0_i e_i - v_i) / tau + sum_j f_ij + f_iW + f_i^group

* people and the robot ``j`` (the robot is one more agent, of its own radius, standing):
  ``f_ij = [A w(phi_ij) exp((r_ij - d_ij) / B) + k g(r_ij - d_ij)] n_ij
  + kappa g(r_ij - d_ij) ((v_j - v_i) . t_ij) t_ij``, with ``d_ij`` the distance of the centres,
  ``r_ij`` the sum of the radii, ``n_ij`` the unit vector from ``j`` to ``i``, ``t_ij`` its normal,
  ``g(x) = max(x, 0)`` (the body terms act only on contact) and the anisotropy
  ``w(phi) = lambda + (1 - lambda) (1 + cos phi) / 2`` (``phi`` the angle between ``i``'s walking
  direction and ``-n_ij``: people react mostly to what is in front of them);
* walls and furniture: the same exponential and body terms from the nearest obstacle
  (:attr:`lidarflow.sim.world.World.field`), strength ``A_w``, range ``B_w``;
* groups: each member is pulled towards the centre of its group's members by ``cohesion``
  (m/s^2) once further than ``(n - 1) / 2`` m from it. A group's leader picks the goals, stops
  and exits; the others share them and appear beside the leader when it appears.

Speeds, stops (log-normal durations) and group sizes are :class:`SocialConfig`'s
(``docs/research/walkers``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from lidarflow.errors import SimError
from lidarflow.sim.people import OFF, STOP, Crowd, PeopleConfig
from lidarflow.sim.world import World

__all__ = ["SocialConfig", "SocialCrowd", "pair_forces", "wall_forces"]


@dataclass(frozen=True)
class SocialConfig:
    """The social-force walkers' parameters (SI units, forces per unit mass).

    ``speed_mean``/``speed_std`` the preferred speeds (clipped to the people's
    ``speed_range``); ``group_sizes`` the chances of a group of one, two or three;
    ``stop_prob`` the chance of stopping at a goal, ``stop_median``/``stop_sigma`` the
    log-normal stop duration (s), at most ``stop_max``."""

    relax_time: float = 0.5
    strength: float = 2.0
    reach: float = 0.2
    anisotropy: float = 0.3
    wall_strength: float = 5.0
    wall_reach: float = 0.15
    body: float = 1500.0
    friction: float = 3000.0
    radius: float = 0.25
    cohesion: float = 1.5
    speed_mean: float = 1.1
    speed_std: float = 0.25
    group_sizes: tuple[float, float, float] = (0.7, 0.25, 0.05)
    stop_prob: float = 0.1
    stop_median: float = 1.0
    stop_sigma: float = 0.6
    stop_max: float = 5.0

    def __post_init__(self) -> None:
        if min(self.relax_time, self.reach, self.wall_reach, self.radius) <= 0:
            raise SimError(f"social walkers: times and lengths must be > 0: {self}")
        if len(self.group_sizes) != 3 or abs(sum(self.group_sizes) - 1) > 1e-9:
            raise SimError(f"group_sizes must be 3 chances summing to 1, got {self.group_sizes}")


def pair_forces(
    pos: np.ndarray,
    vel: np.ndarray,
    facing: np.ndarray,
    others: np.ndarray,
    others_vel: np.ndarray,
    radii: np.ndarray,
    config: SocialConfig,
    self_index: bool = True,
) -> np.ndarray:
    """``(N, 2)`` the sum of ``f_ij`` (module docstring) on people at ``pos (N, 2)`` (velocity
    ``vel``, unit walking direction ``facing``) from agents at ``others (M, 2)`` (velocity
    ``others_vel``, radius ``radii (M,)``). With ``self_index``, ``others[i]`` is person ``i``
    itself and is left out."""
    c = config
    diff = pos[:, None, :] - others[None, :, :]
    dist = np.maximum(np.hypot(diff[..., 0], diff[..., 1]), 1e-9)
    if self_index:
        dist[np.arange(len(pos)), np.arange(len(pos))] = np.inf
    n = diff / dist[..., None]
    overlap = c.radius + radii[None, :] - dist
    contact = np.maximum(overlap, 0.0)
    cos_phi = -(n * facing[:, None, :]).sum(-1)
    weight = c.anisotropy + (1 - c.anisotropy) * (1 + cos_phi) / 2
    push = c.strength * weight * np.exp(overlap / c.reach) + c.body * contact
    t = np.stack([-n[..., 1], n[..., 0]], axis=-1)
    slide = ((others_vel[None, :, :] - vel[:, None, :]) * t).sum(-1)
    return (push[..., None] * n + (c.friction * contact * slide)[..., None] * t).sum(1)


def wall_forces(distance: np.ndarray, away: np.ndarray, config: SocialConfig) -> np.ndarray:
    """``(N, 2)`` the push of the nearest obstacle at ``distance (N,)`` m, in the unit
    direction ``away (N, 2)`` from it."""
    c = config
    overlap = c.radius - np.asarray(distance)
    mag = c.wall_strength * np.exp(overlap / c.wall_reach) + c.body * np.maximum(overlap, 0.0)
    return mag[:, None] * away


class SocialCrowd(Crowd):
    """:class:`~lidarflow.sim.people.Crowd` with the social forces, groups and stops of the
    module docstring (``social`` its parameters; the people's ``speed_*`` and ``stop_*`` are
    ``social``'s)."""

    substep = 0.025  # the body forces are stiff: k = 1500 s^-2 wants steps under 0.05 s

    def __init__(
        self,
        world: World,
        config: PeopleConfig,
        rng: np.random.Generator,
        sensor: np.ndarray,
        fov: float,
        reach: float,
        social: SocialConfig | None = None,
    ) -> None:
        self.social = social or SocialConfig()
        s = self.social
        config = replace(
            config, speed_mean=s.speed_mean, speed_std=s.speed_std, stop_prob=s.stop_prob
        )
        super().__init__(world, config, rng, sensor, fov, reach)
        n = config.count
        self.leader = np.arange(n)
        i = 0
        while i < n:
            size = min(int(rng.choice(3, p=s.group_sizes)) + 1, n - i)
            self.leader[i : i + size] = i
            i += size
        # a group walks at the pace of its leader, give or take a little
        self.speed0 = self.speed0[self.leader] * rng.uniform(0.95, 1.05, n)
        for f in self._followers():
            self.state[f] = OFF
        self._follow()

    def _followers(self) -> np.ndarray:
        return np.flatnonzero(self.leader != np.arange(len(self.leader)))

    def _deciders(self) -> np.ndarray:
        return np.flatnonzero(self.leader == np.arange(len(self.leader)))

    def _stop(self, i: int) -> None:
        s = self.social
        self.state[i] = STOP
        self.timer[i] = min(s.stop_max, self.rng.lognormal(math.log(s.stop_median), s.stop_sigma))
        self.turn[i] = 0.0

    def _update_states(self, dt: float, sensor: np.ndarray) -> None:
        super()._update_states(dt, sensor)
        self._follow()

    def _follow(self) -> None:
        """Followers take their leader's state and waypoint; one whose leader has just
        appeared appears beside it."""
        for f in self._followers():
            lead = self.leader[f]
            if self.state[lead] == OFF:
                self.state[f] = OFF
                continue
            if self.state[f] == OFF:
                self._place(f, lead)
            self.state[f] = self.state[lead]
            self.routes[f] = self.routes[lead]
            self.target[f] = self.target[lead]
            self.final[f] = self.final[lead]
            self.timer[f] = self.timer[lead]

    def _place(self, f: int, lead: int) -> None:
        """Put follower ``f`` beside (else behind) its leader, where there is room."""
        h = self.heading[lead]
        side = np.array([-math.sin(h), math.cos(h)])
        back = -np.array([math.cos(h), math.sin(h)])
        rank = f - lead
        spots = self.pos[lead] + 0.6 * np.array(
            [side * (1 if rank == 1 else -1), back * rank, back * rank + side * 0.5]
        )
        ok = self.world.clearance(spots) >= 0.3
        self.pos[f] = spots[np.argmax(ok)] if ok.any() else self.pos[lead] + 0.05 * back
        self.vel[f] = self.vel[lead]
        self.heading[f] = h
        self.check_pos[f] = self.pos[f]
        self.check_timer[f] = 0.0

    def _forces(self, idx: np.ndarray, robot: np.ndarray, robot_radius: float) -> np.ndarray:
        s = self.social
        pos, vel = self.pos[idx], self.vel[idx]
        force, facing = self._drive(idx, s.relax_time)
        others = np.concatenate([pos, robot[None, :2]])
        others_vel = np.concatenate([vel, np.zeros((1, 2))])
        radii = np.concatenate([np.full(len(pos), s.radius), [robot_radius]])
        force += pair_forces(pos, vel, facing, others, others_vel, radii, s)
        dist_w, away = self.world.field.lookup(pos)
        force += wall_forces(dist_w, away, s) * (dist_w < self.world.field.cap)[:, None]
        return force + self._cohesion(idx)

    def _cohesion(self, idx: np.ndarray) -> np.ndarray:
        """Each group member's pull towards the centre of its group's members present."""
        lead = self.leader[idx]
        same = lead[:, None] == lead[None, :]
        centre = same @ self.pos[idx] / same.sum(1)[:, None]
        d = centre - self.pos[idx]
        dist = np.hypot(d[:, 0], d[:, 1])
        far = dist > (same.sum(1) - 1) / 2
        return np.where(far[:, None], self.social.cohesion * d / np.maximum(dist, 1e-9)[:, None], 0)
