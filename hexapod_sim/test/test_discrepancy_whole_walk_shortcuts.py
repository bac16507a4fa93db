"""The whole-walk replay's shortcuts give what the plain computation gives, on a recorded walk
(bags/discrepancy_walk_demo: a tripod walk over the blocks whose nominal replay leaves the recording
after a few seconds): the compiled loop run from one goal write to the next predicts the reads of a
replay stepped 1 ms at a time bit for bit; a replay stopped once it is out of step gives the full
replay's in-step verdict and residuals; candidates compared lazily give the minimum of the full
comparisons; and the search with them finds the value of the search that replays every candidate whole.
The writes applied in the compiled loop replay what the Python write loop does, bit for bit."""
import math
from pathlib import Path

import numpy as np
import pytest

from hexapod_model.description import load_robot
from hexapod_model.joints import JOINTS, Joint
from hexapod_model.servo import theta_to_tick
from hexapod_sim.discrepancy import whole_walk as ww
from hexapod_sim.discrepancy import whole_walk_search as wws
from hexapod_sim.discrepancy.effects import BY_NAME
from hexapod_sim.discrepancy.recording import load_recording

BAG = Path(__file__).resolve().parents[2] / 'bags' / 'discrepancy_walk_demo'
SCOPE = (Joint(6, 'femur'),)


@pytest.fixture(scope='module')
def robot():
    return load_robot()


@pytest.fixture(scope='module')
def rec(robot):
    r = load_recording(BAG, robot)
    assert r.ground is not None and r.ground.terrain == 'blocks'
    return r


def _replay_step_by_step(rec, robot, ground, joints, t_end_s):
    """The replay one physics step per call, the output angles read from Python at every step."""
    from hexapod_sim.physics.plant import HexapodSim
    sim = HexapodSim(robot, terrain=ground.terrain, seed=ground.seed, imu_rate_hz=0.0, start_xy_m=ground.start_xy_m)
    sim.reset()
    start = ww._start_angles(rec, sim)
    if start is not None:
        sim.reset(joint_angles=start)
    dt = sim.dt
    n = int(math.ceil(t_end_s / dt)) + 2
    writes = rec.writes_by_tick(dt)
    cols = [JOINTS.index(j) for j in joints]
    grid = np.empty((n, len(cols)))
    for k in range(n):
        grid[k] = sim.true_joint_angles()[cols]
        if k in writes:
            sim.sync_write(writes[k])
        sim.step(dt)
    out = {}
    for c, j in enumerate(joints):
        t = rec.states[j].t_s
        t = t[t <= t_end_s]
        x = np.clip((t - robot.joint_effects(j).readout_delay_s) / dt, 0.0, n - 1.0)
        i0 = np.minimum(np.floor(x).astype(np.int64), n - 2)
        f = x - i0
        out[j] = theta_to_tick(grid[i0, c] * (1.0 - f) + grid[i0 + 1, c] * f, robot.servo)
    return out


def test_the_replay_from_write_to_write_predicts_what_the_step_by_step_replay_does(rec, robot):
    joints = [Joint(1, 'coxa'), Joint(6, 'femur'), Joint(3, 'tibia')]
    slow = robot.with_effects([BY_NAME['readout_delay'].make(joints[1:2], 0.004),
                               BY_NAME['backlash'].make(joints[2:], 0.02)])
    for model in (robot, slow):
        want = _replay_step_by_step(rec, model, rec.ground, joints, 1.5)
        got = ww.replay_walk(rec, model, rec.ground, joints, t_end_s=1.5)
        assert set(got) == set(joints)
        for j in joints:
            assert np.array_equal(got[j], want[j]), j


def test_the_writes_applied_in_the_compiled_loop_replay_what_the_python_write_loop_does(rec, robot):
    """The recorded writes applied inside the compiled loop (physics.write_schedule) against a sync write and
    a step from Python per write: the same output angles at every physics step, the same state, in pieces of
    any length; a sim whose goals act later (a goal latency) is replayed through the Python loop."""
    on = [Joint(6, 'femur')]
    models = ((robot, True), (robot.with_effects([BY_NAME['static_friction'].make(on, 0.15)]), True),
              (robot.with_effects([BY_NAME['compliance_deadband'].make(on, 2.0)]), True),
              (robot.with_effects([BY_NAME['backlash'].make(on, 0.02)]), True),
              (robot.with_effects([BY_NAME['goal_latency'].make(rec.joints, 0.002)]), False))
    inputs = ww.ReplayInputs(rec, rec.ground)
    for model, compiled in models:
        fast = ww.WalkReplay(rec, model, rec.ground, t_end_s=2.5, inputs=inputs)
        assert (fast._schedule is not None) is compiled and fast.sim.writes_act_when_written is compiled
        slow = ww.WalkReplay(rec, model, rec.ground, t_end_s=2.5)
        slow._schedule = None                     # the writes from Python, one sync write and one step each
        for t in (0.3, 0.3, 1.234, math.inf):
            assert fast.run_to(t) == slow.run_to(t)
            assert fast.steps == slow.steps
            assert np.array_equal(fast.grid[:fast.steps], slow.grid[:slow.steps])
        assert fast.finished and np.array_equal(fast.sim.data.qpos, slow.sim.data.qpos)
        assert fast.sim.bus_stats == slow.sim.bus_stats and fast._next_write == slow._next_write
        for j in fast.joints:
            assert np.array_equal(fast.pred[j], slow.pred[j])


def test_a_write_the_sim_refuses_is_left_to_the_python_loop():
    from hexapod_sim.physics.write_schedule import WriteSchedule
    good = WriteSchedule.of([(0, {'leg1_coxa': 0.1, 'leg2_tibia': -0.2}), (3, {'leg1_coxa': 0.2})])
    assert good.step.tolist() == [0, 3] and good.start.tolist() == [0, 2, 3]
    assert WriteSchedule.of([(0, {'leg1_coxa': math.nan})]) is None
    assert WriteSchedule.of([(0, {'leg7_coxa': 0.1})]) is None


def test_a_replay_stopped_once_out_of_step_gives_the_whole_replays_verdict(rec, robot):
    joints = list(rec.joints)
    whole = ww.replay_walk(rec, robot, rec.ground, joints)
    res_whole = {j: ww.rec_ticks(rec, robot, j) - p for j, p in whole.items()}
    until = wws.in_step_until(rec, res_whole)
    assert until < rec.duration_s - 5.0                 # the nominal replay leaves this walk early
    replays = wws.Replays(rec, robot, rec.ground)
    res, got = replays.in_step(robot, joints)
    assert got == until
    r = replays.get(robot, joints)
    assert r.steps < r.n / 2                             # it stopped long before the end
    for j in joints:
        before = rec.states[j].t_s < until
        assert np.array_equal(res[j][before], res_whole[j][before]), j
    res2, got2 = replays.in_step(robot, joints, need_s=until + 4.0)   # asked to go on: the same verdict
    assert got2 == until and r.covered_s() >= until + 4.0
    for j in joints:
        judged = rec.states[j].t_s < until + 4.0
        assert np.array_equal(res2[j][judged], res_whole[j][judged]), j


def test_candidates_compared_lazily_give_the_minimum_of_the_whole_comparisons(rec, robot):
    until = 2.0
    fit, _ = wws.search_masks(rec, SCOPE, until)
    cand = BY_NAME['viscous_damping']
    values = [0.01, 0.1, 0.3, 1.5]
    full = []
    replays = wws.Replays(rec, robot, rec.ground)
    for v in values:
        pred = ww.replay_walk(rec, robot.with_effects([cand.make(SCOPE, v)]), rec.ground, SCOPE, t_end_s=until)
        full.append(wws.masked_rms(replays, pred, SCOPE, fit))
    trials = [wws._Trial(replays, robot.with_effects([cand.make(SCOPE, v)]), SCOPE, until, fit) for v in values]
    lazy = wws._settle(trials)
    k = int(np.argmin(full))
    assert int(np.argmin(lazy)) == k and lazy[k] == full[k]
    for c_lazy, c_full in zip(lazy, full):
        assert c_lazy == c_full or (c_lazy == math.inf and c_full > full[k])
    assert any(not t.finished for t in trials)           # some were stopped early


def _search_whole(rec, robot, cand, scope, until_s, fit):
    """The search replaying every candidate value whole: the grid, then golden-section steps that
    evaluate both interior points afresh."""
    replays = wws.Replays(rec, robot, rec.ground)

    def cost(v):
        pred = ww.replay_walk(rec, robot.with_effects([cand.make(scope, v)]), rec.ground, scope, t_end_s=until_s)
        return wws.masked_rms(replays, pred, scope, fit)
    grid = np.geomspace(cand.lo, cand.hi, wws.SEARCH_GRID)
    costs = [cost(float(v)) for v in grid]
    k = int(np.nanargmin(costs))
    a, b = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    best = (float(grid[k]), costs[k])
    g = (math.sqrt(5) - 1) / 2
    for _ in range(wws.SEARCH_REFINE):
        la, lb = math.log(a), math.log(b)
        x1, x2 = math.exp(lb - g * (lb - la)), math.exp(la + g * (lb - la))
        c1, c2 = cost(x1), cost(x2)
        for x, c in ((x1, c1), (x2, c2)):
            if c < best[1]:
                best = (x, c)
        a, b = (a, x2) if c1 < c2 else (x1, b)
    return best


def test_the_search_with_its_shortcuts_finds_the_value_of_the_whole_search(rec, robot):
    until = 1.5
    fit, hold = wws.search_masks(rec, SCOPE, until)
    cand = BY_NAME['viscous_damping']
    want_v, want_c = _search_whole(rec, robot, cand, SCOPE, until, fit)
    v, c, r = wws.search_one(wws.Replays(rec, robot, rec.ground), [], cand, SCOPE, until, fit, lambda msg: None)
    assert (v, c) == (want_v, want_c)
    pred = ww.replay_walk(rec, robot.with_effects([cand.make(SCOPE, v)]), rec.ground, SCOPE, t_end_s=until)
    assert np.array_equal(r.pred[SCOPE[0]], pred[SCOPE[0]])      # its replay is the best value's


def test_a_grid_with_no_value_below_worth_below_gives_nothing_and_is_cut_short(rec, robot, monkeypatch):
    until = 4.0
    fit, _ = wws.search_masks(rec, SCOPE, until)
    cand = BY_NAME['viscous_damping']
    replays = wws.Replays(rec, robot, rec.ground)
    made = []
    init = wws._Trial.__init__

    def counted(self, *a, **k):
        init(self, *a, **k)
        made.append(self)
    monkeypatch.setattr(wws._Trial, '__init__', counted)
    v, c, _ = wws.search_one(replays, [], cand, SCOPE, until, fit, lambda msg: None)
    grid_s = sum(t.t for t in made[:wws.SEARCH_GRID])
    grid_best = min(t.value for t in made[:wws.SEARCH_GRID] if t.finished)
    # a grid value below it: the search of old, bit for bit
    assert wws.search_one(replays, [], cand, SCOPE, until, fit, lambda msg: None,
                          worth_below=grid_best * (1 + 1e-6))[:2] == (v, c)
    made.clear()
    tried = []
    assert wws.search_one(replays, [], cand, SCOPE, until, fit, tried.append, worth_below=0.5 * grid_best) is None
    assert len(tried) == wws.SEARCH_GRID               # the grid only, no golden-section steps
    assert max(t.t for t in made) < until and sum(t.t for t in made) < grid_s      # no value replayed whole
