"""The compiled kernels (cdf_mj.model.kernels, cdf_mj.inference.kernels) against independent
references: the NumPy geometry and occlusion code, NumPy's searchsorted, the same kernels one
row at a time, and the filter's own arrays summed by hand.

Real scenes only: the package scene (models/xml/scene.xml) and a mirrored, rotated and moved
T-junction with other element names, built with tests/junctions.py. Measurements are the
system poses that MuJoCo produced in CDF episodes (``trace=True``), fed to a
:class:`ParticleFilter` tick by tick as the CDF planner does (reset or update, then predict).
N = 200 particles keeps the file fast.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from junctions import junction_scene

from cdf_mj.config import CDFConfig, ScenarioConfig, SceneNames
from cdf_mj.inference import kernels as filter_kernels
from cdf_mj.inference.particle_filter import ParticleFilter
from cdf_mj.inference.resampling import stratified_indexes_from_uniforms, systematic_indexes_from_uniform
from cdf_mj.model import kernels as model_kernels
from cdf_mj.model.driver import (
    DriverModel,
    DriverParams,
    Intent,
    Mode,
    bicycle_step,
    obstacle_control,
    update_belief,
)
from cdf_mj.model.layout import Layout
from cdf_mj.model.occlusion import sight_targets
from cdf_mj.planners import CDFPlanner
from cdf_mj.scenario.episode import run_episode
from cdf_mj.sim.scene import Scene

N = 200
OTHER_NAMES = SceneNames(ego_prefix="me/", obstacle_prefix="them/", ego_start="me_home",
                         obstacle_start="them_home", stop_line="halt", ego_lane="my_lane",
                         conflict="clash", commit="point_of_no_return", route_ego="my_way",
                         route_left="their_cross", route_right="their_away", building_prefix="block")
# Episodes whose measurements drive the filters: a left-turner that never sees the ego (it
# goes through the whole turn), a right-turner, and one of the default scenario.
EPISODES = ((ScenarioConfig(obstacle={"p_left": 1.0, "beta": 0.0}), 0), (ScenarioConfig(obstacle={"p_left": 0.0}), 1),
            (ScenarioConfig(), 3))


@pytest.fixture(scope="module")
def scenes(scene: Scene) -> dict[str, Scene]:
    """The package scene and a mirrored, rotated, moved junction with other names."""
    return {"package": scene,
            "moved": junction_scene(mirror=True, rotation=2.2, center=(30.0, -12.0), names=OTHER_NAMES)}


@pytest.fixture(scope="module")
def traces(scenes: dict[str, Scene]) -> dict[str, list[np.ndarray]]:
    """Per scene, the measured system poses ``(T, 2, 4)`` of the CDF episodes of EPISODES."""
    out = {}
    for name, sc in scenes.items():
        records = [run_episode(cfg, seed, CDFPlanner(CDFConfig(n_particles=N)), sc, label=False, trace=True)
                   for cfg, seed in EPISODES]
        out[name] = [np.array(rec.trace["poses"]) for rec in records if rec.trace is not None]
        assert len(out[name]) == len(EPISODES)
    return out


def _filter(layout: Layout, seed: int = 0, **changes: Any) -> ParticleFilter:
    return ParticleFilter.from_layout(layout, CDFConfig(n_particles=N, **changes), np.random.default_rng(seed),
                                      ScenarioConfig().timing.dt)


def _run(pf: ParticleFilter, poses: np.ndarray, check=None, ticks: int | None = None) -> None:
    """Drive ``pf`` over the measurements as the CDF planner does, calling
    ``check(pf, k, stage)`` after reset, every update and every predict."""
    ticks = len(poses) if ticks is None else min(ticks, len(poses))
    for k in range(ticks):
        if k == 0:
            pf.reset(poses[0])
            stage = "reset"
        else:
            pf.update(poses[k])
            stage = "update"
        if check is not None:
            check(pf, k, stage)
        pf.predict(poses[k])
        if check is not None:
            check(pf, k, "predict")


# ------------------------------------------------------------------------ projection
@pytest.mark.parametrize("which", ["package", "moved"])
def test_tracked_arc_lengths_equal_the_full_search(scenes, traces, which):
    """Every tick of whole episodes: the arc lengths the filter keeps by tracking each
    particle's segment equal Polyline.project's full search (within 1e-9 m) for every
    particle within 3 m of its own route."""
    layout = scenes[which].layout()
    compared, total = 0, 0
    reached = [0.0, 0.0]  # furthest arc length compared, per route [m]

    def check(pf: ParticleFilter, k: int, stage: str) -> None:
        nonlocal compared, total
        arc = pf.arc()
        assert arc.shape == (N,)
        for r in (Intent.LEFT, Intent.RIGHT):
            rows = pf.intent == r
            s_ref, lateral = pf.model.routes[r].project(pf.pose[rows, :2])
            near = np.abs(lateral) < 3.0
            np.testing.assert_allclose(arc[rows][near], s_ref[near], rtol=0, atol=1e-9,
                                       err_msg=f"{which} tick {k} after {stage}, route {r.name}")
            compared += int(near.sum())
            if near.any():
                reached[r] = max(reached[r], float(s_ref[near].max()))
        total += N

    for poses in traces[which]:
        _run(_filter(layout), poses, check)
    assert compared >= 0.9 * total  # the particles follow the measured car
    for r in (Intent.LEFT, Intent.RIGHT):  # and the comparison covered the turn and beyond
        route = layout.obstacle_routes[r]
        assert reached[r] > float(route.project(route.points[-2])[0]) + 5.0


@pytest.mark.parametrize("which", ["package", "moved"])
def test_tracked_projection_follows_moves_both_ways(scenes, which):
    """The tracking projection kernel (kernels.project_rows), started from the segment of a
    point's previous place on its route, gives Polyline.project's full-search arc length
    (within 1e-9 m) after a move of less than the shortest segment, forwards or backwards
    (across waypoints either way), 1 m off the route at most."""
    layout = scenes[which].layout()
    model = DriverModel.of_world(layout, ScenarioConfig())
    table = model.table
    rng = np.random.default_rng(12)
    n = 4000
    for r, route in enumerate(model.routes):
        shortest = float(np.min(np.hypot(*np.diff(route.points, axis=0).T)))
        s0 = rng.uniform(0.0, 45.0, n)
        s1 = np.clip(s0 + rng.uniform(-0.95, 0.95, n) * shortest, 0.0, None)
        rows = np.full(n, r, dtype=np.int64)
        before = route.point_at(s0) + rng.uniform(-0.7, 0.7, (n, 2))
        after = route.point_at(s1) + rng.uniform(-0.7, 0.7, (n, 2))
        seg = np.full(n, -1, dtype=np.int64)
        s_before = model_kernels.project_rows(table.table, table.nseg, rows, before, seg)  # full search
        np.testing.assert_allclose(s_before, route.project(before)[0], rtol=0, atol=1e-9)
        kept = seg.copy()
        s_after = model_kernels.project_rows(table.table, table.nseg, rows, after, seg)  # tracked
        np.testing.assert_allclose(s_after, route.project(after)[0], rtol=0, atol=1e-9,
                                   err_msg=f"{which}, route {Intent(r).name}")
        assert (seg > kept).sum() > 100 and (seg < kept).sum() > 100  # waypoints crossed both ways


# ------------------------------------------------------------------------ line of sight
@pytest.mark.parametrize("which", ["package", "moved"])
def test_line_of_sight_kernel_equals_the_numpy_occluders(scenes, which):
    """ParticleFilter.sees_ego (compiled) equals Occluders.visible from each particle's eye to
    the ego's hull corners and centre (NumPy), for random particle poses around the
    junction, eyes inside and just outside buildings, and ego poses along its route."""
    layout = scenes[which].layout()
    occ, obstacle, ego = layout.occluders, layout.obstacle, layout.ego
    rng = np.random.default_rng(11)
    pf = _filter(layout)
    pf.reset(np.stack([layout.ego_start, layout.obstacle_start]))
    centre = np.asarray(layout.conflict)

    # Eyes spread around the junction, then eyes inside and just outside each building (the
    # pose put so that the eye lands there).
    spread = centre + rng.uniform(-35.0, 35.0, (400, 2))
    near = []
    for b in range(len(occ)):
        c, s = math.cos(occ.heading[b]), math.sin(occ.heading[b])
        local = rng.uniform(-1.1, 1.1, (60, 2)) * occ.half[b]  # inside and up to 10 % outside
        near.append(occ.center[b] + local @ np.array([[c, s], [-s, c]]))
    eyes_xy = np.concatenate([spread, *near])
    theta = rng.uniform(-math.pi, math.pi, len(eyes_xy))
    off = obstacle.eye_offset
    ct, st = np.cos(theta), np.sin(theta)
    pose = np.column_stack([eyes_xy[:, 0] - (ct * off[0] - st * off[1]),
                            eyes_xy[:, 1] - (st * off[0] + ct * off[1]), theta,
                            rng.uniform(0.0, 8.0, len(eyes_xy))])
    np.testing.assert_allclose(obstacle.eye(pose)[:, :2], eyes_xy, atol=1e-9)

    route = layout.route_ego
    inside_any = np.zeros(len(eyes_xy), dtype=bool)
    for b in range(len(occ)):
        c, s = math.cos(occ.heading[b]), math.sin(occ.heading[b])
        d = eyes_xy - occ.center[b]
        inside_any |= (np.abs(d @ [c, s]) < occ.half[b, 0]) & (np.abs(d @ [-s, c]) < occ.half[b, 1])
    assert inside_any.sum() >= 100  # eyes inside buildings are part of the sample

    seen_counts = []
    for s_ego in np.linspace(60.0, 200.0, 8):  # the ego from far before to past the junction
        xy, ahead = route.point_at(s_ego), route.point_at(s_ego + 1.0)
        ego_pose = np.array([*xy, math.atan2(ahead[1] - xy[1], ahead[0] - xy[0]), 13.4])
        pf.set_ego(np.stack([ego_pose, layout.obstacle_start]))
        pf.pose = pose.copy()  # a new pose array: the filter's line-of-sight cache starts afresh
        got = pf.sees_ego()
        targets = sight_targets(ego, ego_pose)  # one pose: the plain-float path the filter takes
        np.testing.assert_array_equal(targets, sight_targets(ego, ego_pose[None])[0])  # = the array path
        want = occ.visible(obstacle.eye(pose), targets)
        np.testing.assert_array_equal(got, want, err_msg=f"{which}, ego at s = {s_ego:.1f} m")
        np.testing.assert_array_equal(pf.sees_ego(), want)  # from the cache, the same
        seen_counts.append(int(want.sum()))
    assert min(seen_counts) > 0 and max(seen_counts) < len(pose)  # both answers occur


# ------------------------------------------------------------------------ resampling
def _searchsorted_reference(w: np.ndarray, u: np.ndarray) -> np.ndarray:
    """numpy.searchsorted of positions (i + u_i) / N (one u for all when len(u) == 1),
    clamped below 1, in the normalised cumulative sum whose last element is set to 1.0."""
    c = np.cumsum(w)
    c = c / c[-1]
    c[-1] = 1.0
    n = len(w)
    positions = np.minimum((np.arange(n) + u) / n, np.nextafter(1.0, 0.0))
    return np.searchsorted(c, positions, side="right")


def _weight_cases(rng: np.random.Generator) -> list[tuple[str, np.ndarray]]:
    cases = []
    for n in (1, 2, 7, 100, 1000):
        cases.append((f"uniform random n={n}", rng.random(n)))
        cases.append((f"unnormalised n={n}", rng.random(n) * 1e3))
        w = rng.random(n)
        w[rng.random(n) < 0.5] = 0.0
        if not w.any():
            w[-1] = 1.0
        cases.append((f"half zeros n={n}", w))
        for j in sorted({0, n // 2, n - 1}):
            one = np.zeros(n)
            one[j] = 1.0
            cases.append((f"one-hot {j} of n={n}", one))
        cases.append((f"tiny n={n}", rng.random(n) * 1e-300 + 5e-324))
        mixed = np.where(rng.random(n) < 0.3, 1.0, 1e-18 * rng.random(n))
        cases.append((f"1 and 1e-18 n={n}", mixed))
        normalised = rng.random(n)
        cases.append((f"normalised n={n}", normalised / normalised.sum()))
    return cases


def test_resampling_kernel_equals_searchsorted():
    """The compiled resampling search (kernels.resample_indexes) picks exactly the indexes of
    numpy.searchsorted on the normalised cumulative sum (last element 1.0) at positions
    (i + u_i) / N clamped below 1, one uniform per particle (stratified) or one for all
    (systematic), and so do resampling.stratified_indexes_from_uniforms and
    systematic_indexes_from_uniform, for zero, one-hot and tiny weights and uniforms at 0
    and just below 1."""
    rng = np.random.default_rng(5)
    below_one = np.nextafter(1.0, 0.0)
    for label, w in _weight_cases(rng):
        n = len(w)
        for u in (rng.random(n), np.zeros(n), np.full(n, below_one), np.where(rng.random(n) < 0.5, 0.0, below_one)):
            want = _searchsorted_reference(w, u)
            got = filter_kernels.resample_indexes(np.ascontiguousarray(w), np.ascontiguousarray(u))
            np.testing.assert_array_equal(got, want, err_msg=label)
            np.testing.assert_array_equal(stratified_indexes_from_uniforms(w, u), want, err_msg=label)
            assert np.all(w[got] > 0.0), label  # a particle of weight zero is never picked
            assert np.all(np.diff(got) >= 0), label
        for u0 in (0.0, float(rng.random()), below_one):
            want = _searchsorted_reference(w, np.array([u0]))
            got = filter_kernels.resample_indexes(np.ascontiguousarray(w), np.array([u0]))
            np.testing.assert_array_equal(got, want, err_msg=f"{label}, systematic u = {u0!r}")
            np.testing.assert_array_equal(systematic_indexes_from_uniform(w, u0), want, err_msg=label)
            assert np.all(w[got] > 0.0), label


# ------------------------------------------------------------------------ driver
def _random_rows(layout: Layout, model: DriverModel, n: int, rng: np.random.Generator):
    """Random driver inputs near the obstacle's routes: poses, modes, beliefs, intents,
    parameters (N,) arrays and stop flags."""
    intent = rng.integers(0, 2, n)
    s = rng.uniform(0.0, 40.0, n)
    xy = np.empty((n, 2))
    heading = np.empty(n)
    for r in (0, 1):
        rows = intent == r
        route = model.routes[r]
        p, q = route.point_at(s[rows]), route.point_at(s[rows] + 0.5)
        xy[rows] = p + rng.normal(0.0, 0.5, (int(rows.sum()), 2))
        heading[rows] = np.arctan2(q[:, 1] - p[:, 1], q[:, 0] - p[:, 0]) + rng.normal(0.0, 0.3, int(rows.sum()))
    pose = np.column_stack([xy, heading, rng.uniform(0.0, 9.0, n)])
    ego_s = rng.uniform(0.0, 250.0, n)
    ego_xy = layout.route_ego.point_at(ego_s)
    ego_ahead = layout.route_ego.point_at(ego_s + 1.0)
    belief = np.column_stack([ego_xy + rng.normal(0.0, 0.5, (n, 2)),
                              np.arctan2(ego_ahead[:, 1] - ego_xy[:, 1], ego_ahead[:, 0] - ego_xy[:, 0]),
                              rng.uniform(-0.5, 15.0, n)])
    params = DriverParams(accel=rng.uniform(1.5, 3.0, n), turn_speed=rng.uniform(6.0, 10.0, n),
                          yield_brake=rng.uniform(3.0, 5.0, n), critical_gap=rng.uniform(4.0, 7.0, n),
                          clear_distance=rng.uniform(7.0, 13.0, n))
    return pose, rng.integers(0, 4, n), belief, rng.random(n) < 0.6, intent, params, rng.random(n) < 0.5


@pytest.mark.parametrize("which", ["package", "moved"])
def test_obstacle_control_rows_equal_one_row_at_a_time(scenes, which):
    """obstacle_control on N rows with per-row parameters and stop flags returns exactly
    what N calls of one row each (float parameters, one bool) return."""
    layout = scenes[which].layout()
    model = DriverModel.of_world(layout, ScenarioConfig())
    rng = np.random.default_rng(3)
    n = 300
    pose, mode, belief, has, intent, params, may_go = _random_rows(layout, model, n, rng)
    u, new = obstacle_control(model, pose, mode, belief, has, intent, params, may_go)
    assert u.shape == (n, 2) and new.shape == (n,)
    for i in range(n):
        one = DriverParams(*(float(np.asarray(getattr(params, f))[i]) for f in
                             ("accel", "turn_speed", "yield_brake", "critical_gap", "clear_distance")))
        ui, ni = obstacle_control(model, pose[i], mode[i:i + 1], belief[i], has[i:i + 1], intent[i:i + 1], one,
                                  bool(may_go[i]))
        np.testing.assert_array_equal(ui[0], u[i], err_msg=f"row {i}")
        assert ni[0] == new[i], i
    # The inputs reach every branch: all four new modes and both signs of steering occur.
    assert set(new.tolist()) == {int(m) for m in Mode}
    assert (u[:, 1] > 0).any() and (u[:, 1] < 0).any()


@pytest.mark.parametrize("which", ["package", "moved"])
def test_kept_segment_drives_as_the_full_search(scenes, which):
    """Cars driven along each route, from the start pose to the far end: obstacle_control
    with a kept ``segment`` array (updated in place) gives at every tick exactly the
    controls and modes it gives without one (full search)."""
    layout = scenes[which].layout()
    cfg = ScenarioConfig()
    model = DriverModel.of_world(layout, cfg)
    n = 4
    params = DriverParams(accel=np.array([1.5, 2.0, 2.5, 3.0]), turn_speed=np.array([6.0, 7.5, 9.0, 10.0]),
                          yield_brake=np.full(n, 4.0), critical_gap=np.full(n, 5.0),
                          clear_distance=np.full(n, 10.0))
    for intent in (Intent.LEFT, Intent.RIGHT):
        route = model.routes[intent]
        pose = np.repeat(layout.obstacle_start[None], n, axis=0)
        mode = np.full(n, int(Mode.WAITING))
        belief, has = np.zeros((n, 4)), np.zeros(n, dtype=bool)
        intents = np.full(n, int(intent))
        segment = np.full(n, -1, dtype=np.int64)
        segments_seen = set()
        for tick in range(400):
            u, new = obstacle_control(model, pose, mode, belief, has, intents, params, True, segment=segment)
            u_ref, new_ref = obstacle_control(model, pose, mode, belief, has, intents, params, True)
            np.testing.assert_array_equal(u, u_ref, err_msg=f"{which} {intent.name} tick {tick}")
            np.testing.assert_array_equal(new, new_ref)
            assert np.all(segment >= 0)
            segments_seen.update(segment.tolist())
            pose, mode = bicycle_step(pose, u, cfg.timing.dt, model.wheelbase), new
            s, lateral = route.project(pose[:, :2])
            assert np.abs(lateral).max() < 1.0  # it follows its route
            if s.min() > route.length - 5.0:
                break
        else:
            pytest.fail(f"{intent.name}: the cars did not reach the end of the route in 400 ticks")
        assert segments_seen == set(range(len(route.points) - 1))  # every segment tracked through
        assert set(mode.tolist()) == {int(Mode.COMMITTED)}


def test_update_belief_dead_reckons_held_beliefs_and_takes_observations():
    """update_belief: an observed driver takes the (shared) observation; a held belief moves
    v * dt along its heading, heading kept (the bicycle with no control), tick after tick;
    a driver with no belief and no observation keeps none."""
    rng = np.random.default_rng(9)
    n, dt, wheelbase = 500, 0.1, 2.7
    belief = np.column_stack([rng.uniform(-50, 50, (n, 2)), rng.uniform(-math.pi, math.pi, n),
                              rng.uniform(0.0, 15.0, n)])
    has = rng.random(n) < 0.7
    observed = rng.random(n) < 0.3
    observation = np.array([-12.0, -1.85, 0.05, 11.0])
    before = belief.copy()
    new, new_has = update_belief(belief, has, observed, observation, dt, wheelbase)
    np.testing.assert_array_equal(belief, before)  # inputs untouched
    np.testing.assert_array_equal(new[observed], np.broadcast_to(observation, (int(observed.sum()), 4)))
    np.testing.assert_array_equal(new_has, has | observed)
    held = has & ~observed
    step = belief[held, 3] * dt
    np.testing.assert_allclose(new[held, 0], belief[held, 0] + step * np.cos(belief[held, 2]), rtol=0, atol=1e-12)
    np.testing.assert_allclose(new[held, 1], belief[held, 1] + step * np.sin(belief[held, 2]), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(new[held, 2:], belief[held, 2:])
    np.testing.assert_allclose(new[held], bicycle_step(belief[held], np.zeros(2), dt, wheelbase), rtol=0,
                               atol=1e-12)
    none = ~has & ~observed
    assert not new_has[none].any()
    # Ten ticks without observations: ten steps of v * dt along the same heading.
    carried, carried_has = belief, has
    for _ in range(10):
        carried, carried_has = update_belief(carried, carried_has, np.zeros(n, dtype=bool), observation, dt,
                                             wheelbase)
    np.testing.assert_allclose(carried[has, 0], belief[has, 0] + 10 * dt * belief[has, 3] * np.cos(belief[has, 2]),
                               rtol=0, atol=1e-9)
    np.testing.assert_allclose(carried[has, 1], belief[has, 1] + 10 * dt * belief[has, 3] * np.sin(belief[has, 2]),
                               rtol=0, atol=1e-9)
    np.testing.assert_array_equal(carried_has, has)


def test_bicycle_step_broadcasts_both_arguments():
    """bicycle_step broadcasts states and controls against each other (either side
    stretched, views not contiguous) and each result equals the step of that one pair."""
    rng = np.random.default_rng(4)
    dt, wheelbase = 0.1, 2.7
    x = np.column_stack([rng.normal(0, 10, (3, 2)), rng.uniform(-3, 3, 3), rng.uniform(0, 15, 3)]).reshape(3, 1, 4)
    u = np.column_stack([rng.uniform(-5, 3, 5), rng.uniform(-0.6, 0.6, 5)]).reshape(1, 5, 2)
    x[2, 0, 3] = 0.2  # slow enough for the braking controls to stop it: speed kept >= 0
    out = bicycle_step(x, u, dt, wheelbase)
    assert out.shape == (3, 5, 4)
    assert (out[..., 3] == 0.0).any()
    for i in range(3):
        for j in range(5):
            xi, uj = x[i, 0], u[0, j]
            step = xi[3] * dt
            want = [xi[0] + step * math.cos(xi[2]), xi[1] + step * math.sin(xi[2]),
                    xi[2] + step / wheelbase * math.tan(uj[1]), max(xi[3] + uj[0] * dt, 0.0)]
            np.testing.assert_allclose(out[i, j], want, rtol=0, atol=1e-12)
            np.testing.assert_array_equal(out[i, j], bicycle_step(xi, uj, dt, wheelbase))
    one = bicycle_step(x[0, 0], u[0], dt, wheelbase)  # one state, five controls
    assert one.shape == (5, 4)
    np.testing.assert_array_equal(one, out[0])
    strided = np.repeat(x[:, 0], 2, axis=1)[:, ::2]  # (3, 4), every column once, not contiguous
    assert not strided.flags.c_contiguous
    np.testing.assert_array_equal(bicycle_step(strided, u[0, :3], dt, wheelbase),
                                  bicycle_step(x[:, 0].copy(), u[0, :3].copy(), dt, wheelbase))


# ------------------------------------------------------------------------ determinism
def _state(pf: ParticleFilter) -> dict[str, np.ndarray]:
    return {"pose": pf.pose.copy(), "mode": pf.mode.copy(), "belief": pf.belief.copy(),
            "has_belief": pf.has_belief.copy(), "intent": pf.intent.copy(), "theta": pf.theta.copy(),
            "logw": np.array(pf.logw), "weights": pf.weights.copy()}


def _assert_same(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> None:
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def _global_random_state() -> tuple:
    """NumPy's global (legacy) random state, to check that nothing draws from it."""
    state: Any = np.random.get_state()  # noqa: NPY002
    name, key, pos, has_gauss, gauss = state
    return name, key.tolist(), pos, has_gauss, gauss


def test_same_seed_same_filter_and_draws_only_from_its_own_generator(scenes, traces):
    """Two filters seeded with default_rng(7) and fed the same 30 measurements end
    bit-identical (poses, modes, beliefs, intents, parameters, weights); a third run
    interleaved tick by tick with a filter of another seed ends the same too, and the
    global NumPy random state is never touched."""
    layout = scenes["package"].layout()
    poses = traces["package"][2]
    assert len(poses) >= 30
    global_before = _global_random_state()

    first = _filter(layout, seed=7)
    _run(first, poses, ticks=30)
    second = _filter(layout, seed=7)
    _run(second, poses, ticks=30)
    _assert_same(_state(first), _state(second))
    assert first.rng.bit_generator.state == second.rng.bit_generator.state
    assert first.rng.bit_generator.state != np.random.default_rng(7).bit_generator.state  # it drew

    mine, other = _filter(layout, seed=7), _filter(layout, seed=8)
    for k in range(30):  # lockstep: each stage of `mine` followed by the same stage of `other`
        for pf in (mine, other):
            pf.reset(poses[0]) if k == 0 else pf.update(poses[k])
        for pf in (mine, other):
            pf.predict(poses[k])
    _assert_same(_state(first), _state(mine))
    with pytest.raises(AssertionError):  # another seed is another filter
        _assert_same(_state(first), _state(other))
    assert _global_random_state() == global_before


# ------------------------------------------------------------------------ posterior
@pytest.mark.parametrize("which", ["package", "moved"])
def test_posterior_equals_weighted_sums(scenes, traces, which):
    """At every tick of whole episodes: P(left) and P(seen) are the sums of the weights of
    the left-turners and of the drivers with a belief; P(cutoff) is the weighted sum of
    cutoff_probability while the ego is exposed, else 0; all within [0, 1]."""
    layout = scenes[which].layout()
    exposed_ticks = [0, 0]

    def check(pf: ParticleFilter, k: int, stage: str) -> None:
        post = pf.posterior()
        w = pf.weights
        p_cut = pf.cutoff_probability()
        where = f"{which} tick {k} after {stage}"
        assert post.p_left == pytest.approx(w[pf.intent == Intent.LEFT].sum(), abs=1e-12), where
        assert post.p_right == pytest.approx(w[pf.intent == Intent.RIGHT].sum(), abs=1e-12), where
        assert post.p_seen == pytest.approx(w[pf.has_belief].sum(), abs=1e-12), where
        assert np.all((p_cut >= 0.0) & (p_cut <= 1.0)), where
        assert np.all(p_cut[pf.intent == Intent.RIGHT] == 0.0), where
        held = (pf.mode == Mode.WAITING) | (pf.mode == Mode.YIELDING)
        assert np.all(p_cut[held] == 0.0), where
        exposed = pf.ego_exposed()
        want = float(np.dot(w, p_cut)) if exposed else 0.0
        assert post.p_cutoff == pytest.approx(want, abs=1e-12), where
        exposed_ticks[exposed] += 1
        for p in (post.p_left, post.p_right, post.p_seen, post.p_cutoff):
            assert 0.0 <= p <= 1.0, where

    for poses in traces[which]:
        _run(_filter(layout), poses, check)
    assert min(exposed_ticks) > 0  # both branches of P(cutoff) were compared


@pytest.mark.parametrize("rule", ["predictive", "paper"])
@pytest.mark.parametrize("which", ["package", "moved"])
def test_cutoff_probability_by_mode_and_intent(scenes, which, rule):
    """With the ego far (140 m before the conflict point, at 13.4 m/s: no pulling out behind
    it): P(cutoff) is 0 for right-turners and held-back drivers, 1 for committed
    left-turners, in [0, 1] for going ones (1 with the paper's rule); with the ego at other
    places along its route it stays in [0, 1] and 0 for right-turners and held-back ones."""
    layout = scenes[which].layout()
    pf = _filter(layout, cutoff_rule=rule)
    pf.reset(np.stack([layout.ego_start, layout.obstacle_start]))
    rng = np.random.default_rng(2)
    model = pf.model
    pose, _, _, _, intent, _, _ = _random_rows(layout, model, N, rng)
    mode = rng.integers(0, 4, N)
    s_conflict = float(layout.route_ego.project(layout.conflict)[0])
    for ahead in (140.0, 60.0, 20.0, 5.0, -3.0, -30.0):  # [m] before the conflict point
        s_ego = s_conflict - ahead
        xy, nxt = layout.route_ego.point_at(s_ego), layout.route_ego.point_at(s_ego + 1.0)
        ego = np.array([*xy, math.atan2(nxt[1] - xy[1], nxt[0] - xy[0]), 13.4])
        pf.set_ego(np.stack([ego, layout.obstacle_start]))
        pf.pose, pf.mode, pf.intent = pose.copy(), mode.copy(), intent.copy()
        p = pf.cutoff_probability()
        left = intent == Intent.LEFT
        assert np.all((p >= 0.0) & (p <= 1.0)), ahead
        assert np.all(p[~left] == 0.0), ahead
        assert np.all(p[(mode == Mode.WAITING) | (mode == Mode.YIELDING)] == 0.0), ahead
        if ahead == 140.0:
            assert pf.ego_exposed()
            committed = left & (mode == Mode.COMMITTED)
            going = left & (mode == Mode.GOING)
            assert committed.sum() >= 10 and going.sum() >= 10
            np.testing.assert_array_equal(p[committed], 1.0)
            if rule == "paper":
                np.testing.assert_array_equal(p[going], 1.0)
            else:
                assert (p[going] < 1.0).any()  # some of them would still look and yield


# ------------------------------------------------------------------------ bad input
def test_bad_input_keeps_its_errors(scenes, traces):
    """A NaN first pose raises ValueError; n_particles=0 raises ValueError; a NaN
    measurement is skipped and counted, changing nothing; predict with a NaN ego drives the
    particles exactly as with the last finite ego."""
    layout = scenes["package"].layout()
    poses = traces["package"][0]
    bad0 = poses[0].copy()
    bad0[1, 2] = np.nan
    with pytest.raises(ValueError, match="finite"):
        _filter(layout).reset(bad0)
    with pytest.raises(ValueError, match="n_particles"):
        CDFConfig(n_particles=0)

    pf = _filter(layout, seed=4)
    _run(pf, poses, ticks=10)
    before = _state(pf)
    meas = poses[10].copy()
    meas[1, 0] = np.nan
    post = pf.update(meas)
    assert pf.skipped_updates == 1 and pf.reinits == 0
    _assert_same(before, _state(pf))
    assert np.isfinite([post.p_left, post.p_seen, post.p_cutoff, post.ess]).all()

    # Predict with a NaN ego and with the last finite ego (the one of the last update):
    # the same particles; with another ego, other beliefs (so the ego is used at all).
    runs = {}
    for name, ego in (("nan", np.full(4, np.nan)), ("last", poses[10][0]), ("other", poses[0][0])):
        pf = _filter(layout, seed=4)
        _run(pf, poses, ticks=10)
        pf.update(poses[10])
        pf.predict(np.stack([ego, poses[10][1]]))
        runs[name] = _state(pf)
    _assert_same(runs["nan"], runs["last"])
    assert np.all(np.isfinite(runs["nan"]["pose"])) and np.all(np.isfinite(runs["nan"]["belief"]))
    assert not np.array_equal(runs["nan"]["belief"], runs["other"]["belief"])


# -------------------------------------------------------------- arrays the filter hands out
def test_a_copy_of_the_filter_runs_on_without_changing_the_original(scenes, traces):
    """A what-if copy (``copy.copy`` of the filter, as a user or ``rollout_assessment``
    makes one) predicts on without touching the original's particles, caches or answers;
    arrays read before a tick keep their values after it."""
    import copy

    poses = traces["package"][0]
    pf = _filter(scenes["package"].layout())
    _run(pf, poses, ticks=9)
    before = {name: getattr(pf, name).copy() for name in ("pose", "mode", "belief", "has_belief", "intent")}
    arc, post, fut = pf.arc(), pf.posterior(), pf.futures()
    held_mode, held_belief = pf.mode, pf.belief
    sim = copy.copy(pf)
    for k in range(15):
        sim.predict(poses[min(9 + k, len(poses) - 1)])
    for name, value in before.items():
        np.testing.assert_array_equal(getattr(pf, name), value, err_msg=name)
    np.testing.assert_array_equal(pf.arc(), arc)
    assert pf.posterior() == post
    np.testing.assert_array_equal(pf.futures().s, fut.s)
    pf.predict(poses[9])
    np.testing.assert_array_equal(held_mode, before["mode"])  # the tick gave pf new arrays
    np.testing.assert_array_equal(held_belief, before["belief"])


def test_particle_arrays_of_the_wrong_shape_or_state_are_clear_errors(scene):
    """Poses and log-weights are read-only (a cache is keyed on them); a particle array of
    another length, or a tick before reset, is one clear error, never an unchecked read."""
    layout = scene.layout()
    pf = _filter(layout)
    with pytest.raises(RuntimeError, match="reset"):
        pf.predict(np.stack([layout.ego_start, layout.obstacle_start]))
    pf.reset(np.stack([layout.ego_start, layout.obstacle_start]))
    with pytest.raises(ValueError, match="read-only"):
        pf.pose[0, 0] = 1.0
    with pytest.raises(ValueError, match="read-only"):
        pf.logw[0] = 1.0
    pf.pose = np.repeat(pf.pose, 2, axis=0)
    with pytest.raises(ValueError, match="pose has 400 rows"):
        pf.predict()
    pf.reset(np.stack([layout.ego_start, layout.obstacle_start]))
    pf.logw = np.zeros(10)
    with pytest.raises(ValueError, match="logw has 10 rows"):
        pf.update(np.stack([layout.ego_start, layout.obstacle_start]))
    model = pf.model
    with pytest.raises(ValueError, match="beliefs"):
        obstacle_control(model, np.zeros((3, 4)), np.zeros(3, dtype=int), np.zeros((2, 4)), np.zeros(3, dtype=bool),
                         np.zeros(3, dtype=int))


def test_a_car_far_inside_a_turn_gets_the_full_search(scene):
    """Tracking walks to a nearer neighbour segment only; a point further than
    TRACK_RADIUS from the route (where that walk can stop at a local nearest, e.g. far
    inside the left turn) gets the full search, from any kept segment."""
    model = _filter(scene.layout()).model
    tab = model.table
    route = model.routes[0]
    rng = np.random.default_rng(3)
    lo, hi = route.points.min(axis=0) - 15.0, route.points.max(axis=0) + 15.0
    xy = rng.uniform(lo, hi, size=(4000, 2))
    want, lateral = route.project(xy)
    for k0 in range(int(tab.nseg[0])):
        got = model_kernels.project_rows(tab.table, tab.nseg, np.zeros(len(xy), dtype=np.int64), xy,
                                         np.full(len(xy), k0, dtype=np.int64))
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9, err_msg=f"kept segment {k0}")
    assert np.sum(np.abs(lateral) > model_kernels.TRACK_RADIUS) > 1000  # far points were in the sample


@pytest.mark.parametrize("radius", [1.5, 2.0, 4.0])
def test_tracking_through_a_hairpin_tighter_than_the_tracking_radius(radius):
    """A route that turns back on itself tighter than TRACK_RADIUS (a hairpin of 1.5-4 m,
    24 segments, then a straight leg back) is tracked exactly: beyond the route's own
    radius of turn the full search takes over, so no point ends on the wrong leg."""
    from cdf_mj.model.geometry import Polyline

    angles = np.linspace(-0.5 * math.pi, 0.5 * math.pi, 25)
    arc = np.column_stack([20.0 + radius * np.cos(angles), radius * np.sin(angles)])
    route = Polyline(np.vstack([[[0.0, -radius]], arc, [[0.0, radius]]]))
    assert model_kernels.tracking_radius(route) == pytest.approx(min(model_kernels.TRACK_RADIUS, radius), rel=0.01)
    tab = model_kernels.RouteTable.of((route,))
    rng = np.random.default_rng(11)
    before = route.point_at(rng.uniform(0.0, route.length, 20000)) + rng.normal(0.0, 1.5, (20000, 2))
    seg = np.full(len(before), -1, dtype=np.int64)
    zeros = np.zeros(len(before), dtype=np.int64)
    model_kernels.project_rows(tab.table, tab.nseg, zeros, np.ascontiguousarray(before), seg)
    after = np.ascontiguousarray(before + rng.uniform(-0.5, 0.5, before.shape))  # a tick's move, tracked
    got = model_kernels.project_rows(tab.table, tab.nseg, zeros, after, seg)
    np.testing.assert_allclose(got, route.project(after)[0], rtol=0, atol=1e-9)


def test_particle_arrays_assigned_in_other_types_are_converted_not_compiled_again(scene):
    """A particle array assigned from outside in another dtype or writable (``pf.pose =
    np.array(pf.pose)``, an int32 mode) is converted at the next stage, so every kernel keeps
    its one compiled variant, and the caller's array is not frozen."""
    layout = scene.layout()
    pf = _filter(layout)
    system = np.stack([layout.ego_start, layout.obstacle_start])
    pf.reset(system)
    pf.predict(system)
    pf.update(system)
    variants = {k: len(k.signatures) for k in (filter_kernels.predict, filter_kernels.weigh, filter_kernels.posterior)}
    mine = np.array(pf.pose)
    pf.pose, pf.mode, pf.intent = mine, pf.mode.astype(np.int32), pf.intent.astype(np.int16)
    pf.predict(system)
    pf.update(system)
    assert {k: len(k.signatures) for k in variants} == variants
    assert pf.mode.dtype == np.int64 and pf.intent.dtype == np.int64 and not pf.pose.flags.writeable
    assert mine.flags.writeable
