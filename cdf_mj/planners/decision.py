"""When to brake: the decision rules a predicting planner is built from (predictor x rule).

A predicting planner (:class:`cdf_mj.planners.base.DecidingPlanner`: ``cdf``, ``imm``,
``cv``) estimates the obstacle's future each tick; its rule turns that estimate into
braking or not:

================  ==========================================================================
ThresholdRule     the paper's rule: brake once the predictor's own alarm probability
                  (the CDF's P(cutoff), the IMM's P(conflict), the CV's predicted conflict)
                  reaches a threshold, and hold the brake to the end
LayeredRule       the graded rule (the default ``cdf``): *anticipate* (slow down gently once
                  a collision going on is likely, ``cdf``'s; or, with the option rule of
                  ``cdf-option``, only once going on a little longer would lose the option
                  of avoiding a likely cut-off with the comfortable brake, at the RSS
                  distance behind a car that merges ahead),
                  *emergency* (the full brake when deferring it would leave a collision
                  unavoidable, with a time margin), *follow* (a time gap behind a merged
                  car, the full brake below the RSS distance), with a dwell, a jerk limit
                  and no deadlock (docs/DECISION.md)
RiskRule          brake at the last safe moment: when the probability of a collision that
                  deferring the brake by one more decision interval (plus a latency
                  margin) would make unavoidable reaches ``RiskConfig.brake`` and braking
                  now is no riskier; release the
                  brake, back to the nominal speed, once that risk of going on is below
                  ``RiskConfig.release``, or, inside the conflict zone, once it is below
                  the risk of staying there
================  ==========================================================================

The risk rule rolls the predictor's hypotheses forward
(:class:`cdf_mj.model.conflict.Futures` along the obstacle's left route, or one
predicted path of poses) against three plans of the ego on its route: going on
(``GO``), going on for ``n_defer`` ticks then braking (``DEFER``), braking now
(``BRAKE``). A hypothesis is *unavoidable if deferred* when it collides under both GO
and DEFER: the ego could neither pass first nor stop in time after waiting. The ego
brakes when the weight of those reaches ``brake`` and braking now collides with no more
weight. Any predictor that gives futures runs with it, so a comparison
of ``cdf`` with ``imm-risk`` isolates the prediction.

Frames and units: world frame, metres, seconds; probabilities in [0, 1].
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from cdf_mj.config import LayeredConfig, RiskConfig
from cdf_mj.model import road
from cdf_mj.model.conflict import (
    BRAKE,
    DEFER,
    GO,
    ConflictMap,
    Futures,
    collision_masses,
    conflict_map,
    ego_plans,
    lane_entry,
    widened,
)
from cdf_mj.model.vehicle import CarGeometry
from cdf_mj.planners.base import DecisionRule, PlannerContext, PlannerInput, Predictor, ThresholdRule

#: Bit masks of :func:`collision_masses`' index: the masses that collide going on and when
#: deferring (unavoidable if deferred), when braking now, and going on.
_INDEX = np.arange(1 << 3)
_DEFERRED = (_INDEX & ((1 << GO) | (1 << DEFER))) == ((1 << GO) | (1 << DEFER))
_BRAKES = (_INDEX & (1 << BRAKE)) != 0
_GOES = (_INDEX & (1 << GO)) != 0

def _unit(total: float) -> float:
    """A probability summed from weights, clipped into [0, 1] against rounding."""
    return min(max(float(total), 0.0), 1.0)


__all__ = ["OPTION", "SLOW", "SLOW_RSS", "Assessment", "DecisionRule", "GivenFutures", "LayeredRule", "Layers",
           "Predictor", "RiskRule", "ThresholdRule"]


@dataclass(frozen=True)
class Assessment:
    """The risk rule's reading of one tick: probabilities (total weight of the hypotheses)
    of a collision under the ego's plans, and where the ego is."""

    deferred: float  # collides both going on and braking after the deferral: unavoidable if deferred
    brake: float  # collides when the ego brakes now
    inside: bool  # the ego is inside the conflict zone
    go: float = math.nan  # collides when the ego goes on (NaN unless assessed with exact=True)


class GivenFutures:
    """A predictor whose futures are given: to ask a rule what it decides for hypotheses
    of your own (tests, scripts, another estimator). ``alarm()`` is 0 (it predicts no
    cut-off of its own for the threshold rule)."""

    def __init__(self, futures: Futures | np.ndarray) -> None:
        self._futures = futures

    def alarm(self) -> float:
        """No alarm of its own."""
        return 0.0

    def futures(self, react_ticks: int) -> Futures | np.ndarray:
        """The futures it was given."""
        return self._futures


class RiskRule:
    """Brake at the last safe moment, release when the risk is gone (module docstring).

    Args:
        config: thresholds, latency margin, horizon and box margin (default :class:`RiskConfig`).
        ego_brake: [m/s^2] the ego's braking in the plans (default: its car's maximum).
    """

    name = "risk"
    releases = True
    history_keys: tuple[str, ...] = ("risk",)

    def __init__(self, config: RiskConfig | None = None, ego_brake: float | None = None) -> None:
        self.config = config or RiskConfig()
        if not isinstance(self.config, RiskConfig):
            raise TypeError(f"config must be a RiskConfig, got {type(self.config).__name__}")
        if ego_brake is not None and not (isinstance(ego_brake, (int, float)) and math.isfinite(ego_brake)
                                          and ego_brake > 0):
            raise ValueError(f"ego_brake={ego_brake!r} is out of range: must be > 0 [m/s^2]")
        self.ego_brake = ego_brake
        self.last: Assessment | None = None

    @property
    def react_ticks(self) -> int:
        """Ticks before a decision deferred now could act: the next decision, plus the latency."""
        return self._defer

    def reset(self, context: PlannerContext) -> None:
        """The junction's conflict map, the ego's limits and its nominal controller."""
        cfg = self.config
        layout, dt = context.layout, context.dt
        half = min(float(layout.ego.hull_half[1]), float(layout.obstacle.hull_half[1]))  # [m]
        if cfg.margin > half:  # 0.3 m is a full-size car's (a third of our car's half width)
            raise ValueError(f"RiskConfig.margin={cfg.margin:g} m is more than half the narrower car's width "
                             f"({half:.3g} m): boxes widened by it collide where the cars pass well apart; for "
                             "a testbed at another scale, scale the configs with the cars (cdf_mj.scaled("
                             f"config, {2 * half / CarGeometry.ours().width:.2g}): its width / our car's)")
        self.map: ConflictMap = conflict_map(layout, cfg.margin)
        self._layout = layout
        self._path_packed: tuple[Any, ...] | None = None  # what _path_masses packs, at its first call
        self._dt = dt
        self._steps = max(1, math.ceil(cfg.horizon / dt - 1e-9))
        self._defer = 1 + math.ceil(cfg.latency / dt - 1e-9)
        brake = self.ego_brake if self.ego_brake is not None else layout.ego.max_brake
        speed = context.nominal_speed
        self._nominal = (speed, context.speed_gain, layout.ego.max_accel, brake)
        need = self._defer * dt + speed / brake  # [s] to defer, then stop from v_nominal
        if cfg.horizon < need:
            raise ValueError(f"RiskConfig.horizon={cfg.horizon:g} s is shorter than the {need:.2f} s the ego "
                             f"needs to defer and then stop from {speed:g} m/s at {brake:g} m/s^2: collisions "
                             "after the horizon would go unseen; give a longer horizon, or, for a testbed at "
                             "another scale, its own nominal speed (cdf_mj.scaled scales the configs)")
        self.last = None

    def plans(self, ego_pose: np.ndarray, q: float | None = None) -> np.ndarray:
        """The ego's arc lengths [m] ``(3, K)`` at ticks ``1..K`` under GO, DEFER and BRAKE,
        from its pose (and its arc length ``q`` [m] on its route, if known)."""
        v_nom, gain, a_max, b = self._nominal
        q0 = self.map.ego_arc(ego_pose) if q is None else q
        return ego_plans(q0, max(float(ego_pose[3]), 0.0), v_nom, gain, a_max, b, self._defer, self._steps,
                         self._dt)

    def assess(self, ego_pose: np.ndarray, futures: Futures | np.ndarray, exact: bool = False) -> Assessment:
        """Collision probabilities of the plans for the predictor's hypotheses. Going on
        alone (``go``) is assessed with ``exact`` only: the rule needs it only together
        with the deferral, and it is the longest roll."""
        q = self.map.ego_arc(ego_pose)
        plans = self.plans(ego_pose, q)
        if isinstance(futures, Futures):
            lazy, gate = (-1, -1) if exact else (GO, DEFER)
            m = collision_masses(futures.weight, futures.s, futures.v, futures.accel, futures.v_max,
                                 futures.delay, plans, self._dt, self.map.ds, self.map.q_lo, self.map.q_hi,
                                 self.map.q_lo_ahead, lazy, gate)
        else:
            m = self._path_masses(plans, np.asarray(futures, dtype=float))
        return Assessment(deferred=_unit(m[_DEFERRED].sum()), brake=_unit(m[_BRAKES].sum()),
                          inside=self.map.inside(q), go=_unit(m[_GOES].sum()) if exact else math.nan)

    def _path_masses(self, plans: np.ndarray, path: np.ndarray) -> np.ndarray:
        """:func:`collision_masses` for one predicted obstacle path ``(K', 4)`` at ticks 1..K':
        1 at the bit mask of the plans whose ego box (on :func:`route_poses` of its arc
        lengths) overlaps the obstacle's at one of the ticks, both widened by the margin;
        one compiled call (:func:`cdf_mj.planners.baseline_kernels.path_mask`), its route
        and cars packed at the first call after :meth:`reset`."""
        from cdf_mj.planners import baseline_kernels as kern  # only cv-risk and cv-layered come here

        if path.ndim != 2 or path.shape[1] != 4:
            raise ValueError(f"a predicted path must be (K, 4) rows [x, y, theta, v] at ticks 1..K, got shape "
                             f"{path.shape}")
        k = min(len(path), plans.shape[1])
        out = np.zeros(1 << len(plans))
        if k == 0:
            return out
        lay, margin = self._layout, self.config.margin
        packed = self._path_packed
        if packed is None:  # once per reset: the ego's route and both widened cars as arrays
            route = lay.route_ego
            last = route.points[-1] - route.points[-2]
            last = last / np.hypot(*last)
            packed = self._path_packed = (kern.slope_table((route,)), last, math.atan2(last[1], last[0]),
                                          kern.car_vector(widened(lay.ego, margin)),
                                          kern.car_vector(widened(lay.obstacle, margin)))
        table, last, heading, ego_car, obstacle_car = packed
        mask = kern.path_mask(np.ascontiguousarray(plans, dtype=np.float64),
                              np.ascontiguousarray(path, dtype=np.float64), k, table.table, table.nseg, table.ends,
                              last, heading, self.map.window, ego_car, obstacle_car)
        out[mask] = 1.0
        return out

    def decide(self, predictor: Predictor, ego_pose: np.ndarray, braking: bool) -> bool:
        """Brake when the deferred risk reaches ``brake`` and braking now is no riskier (where
        every hypothesis collides whatever the ego does, braking at least lowers the speed).
        Once braking, release when that risk is below ``release``, or, inside the conflict
        zone, as soon as it is below the risk of staying (braking on): an ego stopped in
        the zone waits for whoever crosses it next. Where both are certain it brakes on."""
        a = self.last = self.assess(ego_pose, predictor.futures(self._defer))
        if braking:
            release = a.deferred < self.config.release or (a.inside and a.deferred < a.brake)
            return not release
        return a.deferred >= self.config.brake and a.brake <= a.deferred

    def values(self) -> dict[str, float]:
        """``risk``: this tick's probability of a collision made unavoidable by deferring."""
        return {"risk": self.last.deferred if self.last is not None else 0.0}



#: The layered rule's fourth plan (after GO, DEFER, BRAKE): the comfortable brake from now on.
SLOW = 3
#: Its fifth, with ``anticipation = "option"``: going on for ``option_time``, then the
#: comfortable brake.
OPTION = 4
#: Its sixth, with ``anticipation = "option"``: the comfortable brake from now on, as
#: :data:`SLOW`, read for whether it still keeps the RSS distance behind a merged car.
SLOW_RSS = 5
#: The plans whose stop is held to the RSS distance behind a car merged ahead
#: (:func:`collision_masses`' ``rss_rows``): both end in the comfortable brake.
_RSS_ROWS = (1 << OPTION) | (1 << SLOW_RSS)


def _reading(n_plans: int) -> np.ndarray:
    """How the layered rule reads the masses of :func:`collision_masses` over its plans:
    columns deferred (collides going on and deferring the full brake), braking fully now,
    going on, slowing, and (with six plans) the option lost (collides going on and going
    on for ``option_time`` before the comfortable brake, or ends short of the RSS distance
    behind the merged car) and slowing short (collides going on and the comfortable brake
    from now ends short of it); ``masses @ reading`` gives the probabilities in one product."""
    index = np.arange(1 << n_plans)

    def both(a: int, b: int) -> np.ndarray:
        bits = (1 << a) | (1 << b)
        return np.asarray((index & bits) == bits)

    columns = [both(GO, DEFER), (index & (1 << BRAKE)) != 0, (index & (1 << GO)) != 0, (index & (1 << SLOW)) != 0]
    if n_plans > SLOW_RSS:
        columns += [both(GO, OPTION), both(GO, SLOW_RSS)]
    return np.stack(columns, axis=1).astype(float)


_READ = _reading(4)
_READ_OPTION = _reading(6)

#: [rad] The follow layer follows a car ahead in the ego's lane heading at most this far off
#: the ego's way: one still turning in, or standing across the lane, already counts (its
#: speed along the ego's way is its speed times the cosine); one coming the other way does not.
FOLLOW_WITHIN = math.pi / 2


@dataclass(frozen=True)
class Layers:
    """The layered rule's reading of one tick (what ``values()`` keeps per tick)."""

    emergency: float  # P(collision unavoidable if the full brake is deferred), the emergency layer's risk
    emergency_now: float  # P(collision when the full brake starts now)
    go: float  # P(collision if the ego goes on at its nominal speed), the anticipation layer's risk
    slow: float  # P(collision if the ego slows at its comfortable brake from now on)
    inside: bool  # the ego is inside the conflict zone
    gap: float  # [m] to a merged car ahead in the ego's lane (inf: none)
    rss: float  # [m] the RSS safe distance behind it (0: none)
    standoff: bool  # both cars stand: hypotheses of the other pulling away later are left out
    # P(collision going on that going on option_time more would leave beyond the comfortable
    # brake, or short of the RSS distance behind the car merged ahead): the anticipation
    # layer's risk with anticipation="option" (NaN with "go")
    option: float = math.nan
    # P(collision going on that even the comfortable brake from now would leave short of the
    # RSS distance behind the merged car): with anticipation="option", the anticipation
    # escalates to the full brake at `escalate` (default `anticipate`) once it slows (NaN with "go")
    slow_rss: float = math.nan


def _moving(futures: Futures | np.ndarray, stand_speed: float) -> Futures | np.ndarray:
    """Only the hypotheses of a car that moves now (speed above ``stand_speed`` [m/s] and no
    wait ahead of it): a predicted path is kept as it is (it moves as measured)."""
    if not isinstance(futures, Futures):
        return futures
    keep = (futures.v > stand_speed) & (futures.delay <= 0.0)
    return Futures(*(np.ascontiguousarray(getattr(futures, f.name)[keep]) for f in dataclasses.fields(Futures)))


class LayeredRule(RiskRule):
    """The graded rule: anticipate, emergency, follow (:class:`LayeredConfig`,
    docs/DECISION.md). Each tick it returns a command (:meth:`command`): the most the ego
    may accelerate [m/s^2], ``-inf`` for the car's full brake, ``inf`` for none.

    One roll of the predictor's hypotheses against the ego's plans (going on; going on for
    the deferral, then the full brake; the full brake now; the comfortable brake now; with
    ``layers.anticipation = "option"``, going on for ``option_time``, then the comfortable
    brake) gives both predictive layers their probabilities: the anticipation layer reads
    the probability of losing the option (a collision going on that going on
    ``option_time`` more would leave beyond the comfortable brake, or that would leave the
    ego, braking comfortably after it, short of the RSS distance behind the car merged
    ahead: stopping past where that car would stop from its full brake; with ``"go"``, of a
    collision going on), the emergency layer :class:`RiskRule`'s deferred risk with a
    longer deferral (one tick, the latency margin ``risk.latency``,
    ``layers.emergency_margin``, the latency the ego is told and its told position noise
    as time at its nominal speed, twice the std). The follow layer reads the measured
    pose of a car ahead in the ego's lane. With the option rule the anticipation escalates
    to the full brake when, slowing since an earlier tick, the comfortable brake from now
    is still likely (``layers.escalate``, by default ``anticipate``) to leave the ego short
    of that RSS distance behind the car merging ahead (:data:`SLOW_RSS`;
    ``Layers.slow_rss``), before that car is in the
    lane, where the follow layer would take over: RSS's proper response, brought forward
    by the belief; it holds until that is no longer likely (and the emergency layer's
    release rules allow).

    Args:
        layers: the layers' parameters (default :class:`LayeredConfig`).
        risk: the emergency layer's thresholds, latency margin, horizon and box margin
            (default :class:`RiskConfig`).
        ego_brake: [m/s^2] the full brake in the plans (default: the ego car's maximum).
    """

    name = "layered"
    releases = True
    graded = True
    history_keys: tuple[str, ...] = ("risk", "anticipate", "accel")

    def __init__(self, layers: LayeredConfig | None = None, risk: RiskConfig | None = None,
                 ego_brake: float | None = None) -> None:
        super().__init__(risk, ego_brake)
        self.layers = layers or LayeredConfig()
        if not isinstance(self.layers, LayeredConfig):
            raise TypeError(f"layers must be a LayeredConfig, got {type(self.layers).__name__}")

    @property
    def hard_brake(self) -> float:
        """[m/s^2] The deceleration from which a command is a brake (``layers.hard_brake``)."""
        return self.layers.hard_brake

    def reset(self, context: PlannerContext) -> None:
        """The risk rule's map and plans, the emergency layer's deferral, the follow layer's
        limits; no command yet. ValueError for a horizon too short for the deferral or a
        comfortable brake not below the car's full brake."""
        lay, cfg = self.layers, self.config
        noise_time = 2.0 * context.measurement_std[0] / context.nominal_speed  # [s] along-track error, 2 std
        told = context.latency + noise_time
        super().reset(context)  # the emergency deferral is set below, after the horizon check
        dt = context.dt
        self._defer = 1 + math.ceil((cfg.latency + told + lay.emergency_margin) / dt - 1e-9)
        speed, brake = context.nominal_speed, self._nominal[3]
        if cfg.horizon < self._defer * dt + speed / brake:
            raise ValueError(f"RiskConfig.horizon={cfg.horizon:g} s is shorter than the "
                             f"{self._defer * dt + speed / brake:.2f} s the ego needs to defer the full brake "
                             f"({self._defer} ticks with the margins) and then stop from {speed:g} m/s: give a "
                             "longer horizon or smaller margins")
        car = context.layout.ego
        self._max_brake = self.ego_brake if self.ego_brake is not None else car.max_brake
        self._max_accel = car.max_accel
        self._rho = dt + cfg.latency + context.latency  # [s] the ego's response time in the RSS distance
        self._cars = (context.layout.ego, context.layout.obstacle)
        for name in ("comfort_brake", "hard_brake"):
            if getattr(lay, name) >= self._max_brake:
                raise ValueError(f"LayeredConfig.{name}={getattr(lay, name):g} m/s^2 is not below the ego car's full "
                                 f"brake {self._max_brake:g} m/s^2; for a testbed at another scale, scale the configs "
                                 "with the cars (cdf_mj.scaled)")
        self._speed_noise = 2.0 * context.measurement_std[3]  # [m/s] a told speed noise a standing car may show
        # The option plan: going on for option_time (plus a tick and what the ego is told of
        # its latency and noise), then the comfortable brake.
        self._option = lay.anticipation == "option"
        self._option_defer = 1 + math.ceil((lay.option_time + told) / dt - 1e-9)
        # The option is lost short of the RSS distance behind a car in the ego's lane, as the
        # follow layer counts one (FOLLOW_WITHIN), that may brake at its full brake.
        self._lane_from = lane_entry(context.layout, FOLLOW_WITHIN) if self._option else 0
        self._lead_brake = context.layout.obstacle.max_brake
        self._option_risk = math.nan
        self._escalate = lay.escalate if lay.escalate is not None else lay.anticipate
        self._cap = math.inf  # [m/s^2] the command now (its ramp is limited by comfort_jerk)
        self._hard = False  # the full brake is on
        self._hard_since = -math.inf
        self._slowing = False  # the anticipation layer slows the ego
        self._slow_since = -math.inf
        self._stand_since: float | None = None
        self._standoff = False  # latched until the other car moves
        self._lead: tuple[float, np.ndarray] | None = None  # the last measured car ahead: (t, pose)
        self._v_last: float | None = None
        self.last_layers: Layers | None = None
        self.last_command = math.inf

    def plans(self, ego_pose: np.ndarray, q: float | None = None) -> np.ndarray:
        """The ego's arc lengths [m] ``(4, K)`` at ticks ``1..K`` under GO, DEFER (the full
        brake after the emergency layer's deferral), BRAKE (the full brake now) and
        :data:`SLOW` (the comfortable brake now, to a stop); with ``anticipation =
        "option"`` a fifth row, :data:`OPTION` (going on for the option time, then the
        comfortable brake), and a sixth, :data:`SLOW_RSS` (SLOW again, read against the RSS
        distance)."""
        v_nom, gain, a_max, b = self._nominal
        q0 = self.map.ego_arc(ego_pose) if q is None else q
        v0 = max(float(ego_pose[3]), 0.0)
        comfort = self.layers.comfort_brake
        hard = ego_plans(q0, v0, v_nom, gain, a_max, b, self._defer, self._steps, self._dt)
        soft = ego_plans(q0, v0, v_nom, gain, a_max, comfort, 1, self._steps, self._dt)
        rows = [hard, soft[BRAKE:]]
        if self._option:
            rows += [ego_plans(q0, v0, v_nom, gain, a_max, comfort, self._option_defer, self._steps,
                               self._dt)[DEFER:BRAKE], soft[BRAKE:]]
        return np.concatenate(rows)

    def layers_of(self, ego_pose: np.ndarray,
                  futures: Futures | np.ndarray) -> tuple[float, float, float, float, bool]:
        """``(emergency, emergency_now, go, slow, inside)``: the probabilities of a collision
        that deferring the full brake would leave unavoidable, of one when braking fully
        now, of one going on and of one slowing at the comfortable brake, for the
        predictor's hypotheses; and whether the ego is in the conflict zone."""
        read, inside = self._read(ego_pose, futures)
        return read[0], read[1], read[2], read[3], inside

    def _read(self, ego_pose: np.ndarray, futures: Futures | np.ndarray) -> tuple[list[float], bool]:
        """The probabilities of :meth:`layers_of` (and, with the option plan, of losing the
        option: colliding going on and under :data:`OPTION`, which for :class:`Futures` also
        collides where it would stop past where the car merged ahead would stop from its full
        brake, :func:`collision_masses`' RSS rows; and of slowing short of that distance, under
        :data:`SLOW_RSS`; one predicted path is tested by its boxes only) and whether the ego
        is inside."""
        q = self.map.ego_arc(ego_pose)
        plans = self.plans(ego_pose, q)
        if isinstance(futures, Futures):
            rss = ((_RSS_ROWS, self.layers.comfort_brake, self._lane_from, self._lead_brake) if len(plans) > OPTION
                   else (0, 1.0, 0, 1.0))  # the option rule's plans also end short of RSS behind a merged car
            m = collision_masses(futures.weight, futures.s, futures.v, futures.accel, futures.v_max,
                                 futures.delay, plans, self._dt, self.map.ds, self.map.q_lo, self.map.q_hi,
                                 self.map.q_lo_ahead, -1, -1, *rss)
        else:
            m = self._path_masses(plans, np.asarray(futures, dtype=float))
        reading = _READ_OPTION if len(plans) > OPTION else _READ
        return [min(max(float(v), 0.0), 1.0) for v in m @ reading], self.map.inside(q)

    def _follow(self, t: float, poses: np.ndarray) -> tuple[float, float, float, float]:
        """``(accel, gap, rss, need)``: the follow layer's command [m/s^2] behind a car ahead
        in the ego's lane (``inf``: none), the gap to it [m], its RSS distance [m] and the
        deceleration [m/s^2] that stops the ego, after its response time, ``min_gap / 2``
        behind where that car would stop at its full brake (``inf``: no room; 0: none): a
        full brake for the RSS distance is released only once the comfortable brake would
        do. The command is the IDM's, braking at most the comfortable brake. A missed
        measurement of the other car (NaN) keeps the last one, moved on at its speed."""
        ego, lead = poses[0], poses[1]
        if np.isfinite(lead).all():
            self._lead = (t, lead)
        elif self._lead is not None:  # dead-reckoned from the last measurement
            t0, last = self._lead
            x, y, th, v = (float(u) for u in last)
            lead = np.array([x + v * (t - t0) * math.cos(th), y + v * (t - t0) * math.sin(th), th, v])
        ego_car, lead_car = self._cars
        if not (np.isfinite(lead).all()
                and road.in_lane_ahead(self._layout, lead, lead_car, ego, ego_car, within=FOLLOW_WITHIN)):
            return math.inf, math.inf, 0.0, 0.0
        eth, ev = float(ego[2]), float(ego[3])
        lth, lv = float(lead[2]), float(lead[3])
        gap = road.car_gap(ego_car, ego, lead_car, lead)
        v_lead = lv * math.cos(lth - eth)
        lay = self.layers
        rss = road.rss_distance(ev, v_lead, self._rho, self._max_accel, self._max_brake, lead_car.max_brake)
        idm = road.idm(ev, v_lead, gap, a_max=self._max_accel, b=lay.comfort_brake, time_gap=lay.time_gap,
                       min_gap=lay.min_gap, s_star="total", gap_floor=1e-3, max_brake=lay.comfort_brake)
        room = gap - 0.5 * lay.min_gap + max(v_lead, 0.0) ** 2 / (2.0 * lead_car.max_brake) - max(ev, 0.0) * self._rho
        need = max(ev, 0.0) ** 2 / (2.0 * room) if room > 0.0 else math.inf
        return idm, gap, rss, need

    def _stands_off(self, t: float, obs: PlannerInput, v: float) -> bool:
        """Whether the other car is taken to wait for the ego: both have stood (below
        ``stand_speed``, the other not in the ego's lane) for ``standoff``; latched until the
        other is measured moving or in the lane, whatever the ego does meanwhile. A missed
        measurement neither starts nor ends it (the timer runs on)."""
        lay, other = self.layers, obs.poses[1]
        if not np.isfinite(other).all():
            return self._standoff
        moving = abs(float(other[3])) >= lay.stand_speed + self._speed_noise or obs.obstacle_in_lane
        if self._standoff:
            if moving:
                self._standoff, self._stand_since = False, None
            return self._standoff
        if moving or v >= lay.stand_speed:
            self._stand_since = None
        elif self._stand_since is None:
            self._stand_since = t
        elif t - self._stand_since >= lay.standoff - 1e-9:
            self._standoff = True
        return self._standoff

    def command(self, predictor: Predictor, obs: PlannerInput) -> float:
        """This tick's command [m/s^2] (``-inf``: the full brake; ``inf``: none)."""
        lay, dt, t = self.layers, self._dt, obs.t
        ego = obs.poses[0]
        v = max(float(ego[3]), 0.0)
        standoff = self._stands_off(t, obs, v)
        futures = predictor.futures(self._defer)
        if standoff:
            futures = _moving(futures, lay.stand_speed)
        read, inside = self._read(ego, futures)
        emergency, now, go, slow = read[:4]
        self._option_risk = read[OPTION] if self._option else math.nan
        slow_rss = read[SLOW_RSS] if self._option else math.nan
        follow, gap, rss, need = self._follow(t, obs.poses)
        cfg = self.config
        a_now = (v - self._v_last) / dt if self._v_last is not None else 0.0  # [m/s^2] the ego's, last tick
        self._v_last = v
        # Emergency (the full brake), held at least layers.dwell. With the option rule, also
        # once the comfortable slowing, begun on an earlier tick, is likely (`anticipate`) to
        # leave the ego short of the RSS distance behind the car merging ahead: the full brake
        # until it no longer does (RSS's proper response, before that car is in the lane).
        escalate = (self._option and self._slowing and gap == math.inf and not inside
                    and slow_rss >= self._escalate and now <= slow_rss)
        if self._hard:
            release = (emergency < cfg.release or (inside and emergency < now)) and not escalate
            # Behind a car: only once the comfortable brake would stop it behind that car's stop.
            if release and gap >= rss and need <= lay.comfort_brake and t - self._hard_since >= lay.dwell - 1e-9:
                self._hard = False
                self._cap = max(a_now, -lay.comfort_brake)  # the ramp back starts below a hard brake
        elif (emergency >= cfg.brake and now <= emergency) or gap < rss or escalate:
            self._hard, self._hard_since = True, t
        # Anticipation (the comfortable brake), with hysteresis and the same dwell, and only
        # while slowing is the safer of the two: an ego that slows into the conflict it
        # meant to let pass (a slow driver pulling out as it arrives later) goes on instead.
        # Behind a car ahead in its lane the follow layer answers for that car instead (the
        # GO plan does not follow it, so its risk there says nothing of slowing).
        start, stop = self.anticipation(obs, go, slow)
        if gap < math.inf:
            self._slowing = False
        elif self._slowing:
            if stop and t - self._slow_since >= lay.dwell - 1e-9:
                self._slowing = False
        elif start:
            self._slowing, self._slow_since = True, t
        # The command: the full brake at once; any other ramps at comfort_jerk.
        if self._hard:
            self._cap = -self._max_brake
            command = -math.inf
        else:
            target = min(-lay.comfort_brake if self._slowing else math.inf, max(follow, -lay.comfort_brake))
            step = lay.comfort_jerk * dt
            cap = min(self._cap, max(a_now, -lay.comfort_brake) + step)  # a cap above the ego's use does not bind
            if v < 1e-3 and target >= 0.0:  # a standing ego: a negative cap only holds it, so none is kept
                cap = max(cap, 0.0)
            cap = max(cap - step, min(target, cap + step))
            self._cap = cap = min(cap, self._max_accel)
            command = math.inf if cap >= self._max_accel else cap
        self.last = Assessment(deferred=emergency, brake=now, inside=inside, go=go)
        self.last_layers = Layers(emergency=emergency, emergency_now=now, go=go, slow=slow,
                                  inside=inside, gap=gap, rss=rss, standoff=standoff, option=self._option_risk,
                                  slow_rss=slow_rss)
        self.last_command = command
        return command

    def anticipation(self, obs: PlannerInput, go: float, slow: float) -> tuple[bool, bool]:
        """The anticipation layer's choice on this tick: ``(start, stop)``, whether it starts
        slowing the ego (read while it does not slow) and whether it may stop (read while it
        slows, after the dwell), from the probabilities of a collision going on (``go``) and
        slowing at the comfortable brake (``slow``). This rule's: start once its risk reaches
        ``layers.anticipate`` and slowing is the safer of the two; stop below
        ``layers.anticipate_release`` or once slowing is riskier. Its risk is ``go`` with
        ``layers.anticipation = "go"``, and with ``"option"`` the probability of losing the
        option (a collision going on that going on ``option_time`` more would leave beyond
        the comfortable brake, or short of the RSS distance behind the merged car:
        ``Layers.option``). A subclass decides on what it reads here
        (the naive-caution baselines)."""
        lay = self.layers
        risk = self._option_risk if self._option else go
        return risk >= lay.anticipate and slow < go, risk < lay.anticipate_release or slow > go

    def assess(self, ego_pose: np.ndarray, futures: Futures | np.ndarray, exact: bool = False) -> Assessment:
        """:meth:`RiskRule.assess` for this rule's plans: the emergency layer's deferred risk,
        the risk of braking fully now, of going on (always exact here) and whether the ego
        is in the conflict zone."""
        deferred, now, go, _, inside = self.layers_of(ego_pose, futures)
        return Assessment(deferred=deferred, brake=now, inside=inside, go=go)

    def decide(self, predictor: Predictor, ego_pose: np.ndarray, braking: bool) -> bool:
        """Not used: this rule commands (:meth:`command`); TypeError."""
        raise TypeError("LayeredRule gives a graded command: call command(predictor, obs)")

    def values(self) -> dict[str, float]:
        """``risk`` (the emergency layer's), ``anticipate`` (the anticipation's: P(collision
        going on), or with ``anticipation = "option"`` P(losing the option)) and ``accel``
        (the command, a cap on the ego's acceleration, within the car's limits [m/s^2]) of
        this tick."""
        ly = self.last_layers
        accel = min(max(self.last_command, -self._max_brake), self._max_accel) if ly is not None else 0.0
        read = (ly.option if self._option else ly.go) if ly else 0.0
        return {"risk": ly.emergency if ly else 0.0, "anticipate": read, "accel": accel}
