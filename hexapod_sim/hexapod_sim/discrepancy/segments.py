"""Which parts of a recording fit the free-leg model.

On a stand (fixed base, feet in the air) every leg hangs free for the whole recording. In a walk
the stance legs carry the body, so only the swing phases fit: a swing is recognised from the
commands alone as an upward femur motion (swing-up, at least ``min_lift_rad``) followed by the
downward motion that ends it (swing-down) when the goal holds still; the span analysed runs from
``settle_s`` after the lift starts (the foot has left the ground) to ``before_stop_s`` before the
swing-down stops (the ground detector stops the leg at contact, so the last moments may already
touch the ground).

``auto`` mode decides between the two from the data: outside its swing phases a stance leg is
pushed *above* the free-leg prediction by the body's weight, which a hanging leg never shows
(:func:`looks_like_walk`).

:func:`replay_analysed` makes the replay the analysis judges: the given windows, the whole stand, or a
walk's swings with the obstructed ones left out, each started in motion from lift-off (:func:`walk_replay`;
corrected by the body's motion from ``/imu`` where other legs level the body under a swing).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hexapod_model.description import Robot
from hexapod_model.joints import Joint
from hexapod_sim.discrepancy.body_motion import body_motion_correction
from hexapod_sim.discrepancy.recording import Recording, RecordingError
from hexapod_sim.discrepancy.simulate import Replay


def parse_windows(texts) -> list[tuple[float, float]]:
    """``['2.5:10', '12:20']`` -> [(2.5, 10.0), (12.0, 20.0)] (seconds from the start of the bag)."""
    out = []
    for t in texts:
        try:
            a, b = (float(x) for x in str(t).split(':'))
        except ValueError:
            raise RecordingError(f'--time {t!r}: expected START:END in seconds, e.g. 2.5:10') from None
        if not (np.isfinite(a) and np.isfinite(b) and b > a >= 0):
            raise RecordingError(f'--time {t!r}: need 0 <= START < END')
        out.append((a, b))
    return sorted(out)


PHASES = ('swing_up', 'swing_forward', 'swing_down', 'stance', 'leveling')


@dataclass(frozen=True)
class Swing:
    """One swing of a leg, from its commands [s]: swing-up from ``t_up``, swing-forward from
    ``t_forward`` (then the settle pause), swing-down from ``t_down`` to ``t_stop`` (the ground
    detector stopped the leg, or theta_fin)."""

    t_up: float
    t_forward: float
    t_down: float
    t_stop: float


@dataclass(frozen=True)
class LegPhases:
    """The gait phases of one leg: its swings and the spans in which its goals move outside them
    (leveling: the body is moved and levelled on the stance legs); the rest is stance."""

    swings: tuple
    leveling: tuple

    def label(self, t: np.ndarray) -> np.ndarray:
        """Index into :data:`PHASES` for every time in ``t`` [s]."""
        t = np.asarray(t, dtype=float)
        out = np.full(t.shape, PHASES.index('stance'))
        for a, b in self.leveling:
            out[(t >= a) & (t < b)] = PHASES.index('leveling')
        for sw in self.swings:
            out[(t >= sw.t_up) & (t < sw.t_forward)] = PHASES.index('swing_up')
            out[(t >= sw.t_forward) & (t < sw.t_down)] = PHASES.index('swing_forward')
            out[(t >= sw.t_down) & (t < sw.t_stop)] = PHASES.index('swing_down')
        return out


def _goal_grid(rec: Recording, leg: int, t: np.ndarray) -> np.ndarray | None:
    cols = []
    for role in ('coxa', 'femur', 'tibia'):
        cmd = rec.commands.get(Joint(leg, role))
        if cmd is None or len(cmd) < 2:
            if role == 'femur':
                return None
            cols.append(np.zeros(len(t)))
            continue
        i = np.clip(np.searchsorted(cmd.t_s, t, side='right') - 1, 0, None)
        cols.append(cmd.theta_rad[i])
    return np.column_stack(cols)


def gait_phases(rec: Recording, legs, min_lift_rad: float = 0.08, gap_s: float = 0.025,
                min_down_s: float = 0.03, grid_s: float = 0.001) -> dict[int, LegPhases]:
    """Gait phases of every leg of a walk (the cycle of Fig. 4), from its commands alone.

    The goals of a leg move in *runs* (a change at least every ``gap_s``) separated by holds. A run
    in which the femur goal rises by at least ``min_lift_rad`` and ends raised is a swing-up
    followed by swing-forward: both are linear joint-space ramps, so swing-forward starts where the
    per-write goal increment changes. The next run starts with the swing-down (its first goal is the
    measured pose, so it may step either way): the femur goal falls with the coxa goal held, until
    the detector stops the leg (``t_stop``: the last fall; a fall shorter than ``min_down_s`` is no
    swing-down, e.g. two leveling runs on uneven ground). What
    follows in that run, and every other run of the leg, is leveling; holds are stance.
    """
    out: dict[int, LegPhases] = {}
    t_end = rec.duration_s
    t = np.arange(0.0, t_end + grid_s, grid_s)
    gap = max(int(round(gap_s / grid_s)), 1)
    for leg in legs:
        g = _goal_grid(rec, leg, t)
        if g is None:
            out[leg] = LegPhases((), ())
            continue
        d = np.diff(g, axis=0)
        change = np.flatnonzero(np.any(np.abs(d) > 1e-6, axis=1))
        runs = []
        if len(change):
            cut = np.flatnonzero(np.diff(change) > gap)
            starts = np.r_[change[0], change[cut + 1]]
            ends = np.r_[change[cut], change[-1]]
            runs = list(zip(starts, ends))        # first and last change index (change k: g[k] -> g[k+1])
        swings, leveling = [], []
        i = 0
        while i < len(runs):
            a, b = runs[i]
            f = g[a:b + 2, 1]
            if f[-1] - f[0] >= min_lift_rad and f.max() - f[0] >= min_lift_rad and i + 1 < len(runs):
                ks = change[(change >= a) & (change <= b)]
                inc = d[ks]
                # linear ramps: a new one starts where the per-write increment changes
                new_ramp = np.r_[True, np.linalg.norm(inc[1:] - inc[:-1], axis=1)
                                 > 0.2 * np.maximum(np.linalg.norm(inc[:-1], axis=1), 1e-9)]
                ramp_starts = ks[new_ramp]
                rising = [r for r in ramp_starts if d[r, 1] > 1e-6]
                # the last ramp is swing-forward, the rising one before it swing-up; earlier
                # ramps of the run are the leveling that ran straight into the swing
                if len(ramp_starts) >= 2 and ramp_starts[-2] in rising:
                    k_up, k_fwd = ramp_starts[-2], ramp_starts[-1]
                else:
                    k_up, k_fwd = (rising[-1] if rising else a), b + 1
                if k_up > a:
                    leveling.append((float(t[a]), float(t[k_up])))
                a = k_up
                c, e = runs[i + 1]
                k = c + 1          # the first swing-down goal comes from the measured state: any direction
                while k <= e and d[k, 1] <= 1e-9 and abs(d[k, 0]) <= 1e-6:
                    k += 1
                falls = np.flatnonzero(d[c:k, 1] < -1e-6)
                if len(falls) and (falls[-1] + 1) * grid_s >= min_down_s:
                    k_stop = c + falls[-1] + 1
                    swings.append(Swing(float(t[a]), float(t[k_fwd]), float(t[c]), float(t[k_stop])))
                    if k <= e:
                        leveling.append((float(t[k]), float(t[e + 1])))
                    i += 2
                    continue
            leveling.append((float(t[a]), float(t[b + 1])))
            i += 1
        out[leg] = LegPhases(tuple(swings), tuple(leveling))
    return out


LOST_MARGIN_S = 0.05     # a phase this close to a lost span may have been misread from the goals held across it


def _touches(a: float, b: float, lost, margin_s: float) -> bool:
    return any(a < d + margin_s and c - margin_s < b for c, d in lost)


def clear_of_lost(phases: dict, lost, margin_s: float = LOST_MARGIN_S) -> dict[int, LegPhases]:
    """``phases`` without the swings and leveling runs that come within ``margin_s`` of a lost span
    (:attr:`Recording.lost`): across one the goals are held at their last recorded value, so a run may be
    cut in two or two joined, and the reads that would show the motion are gone."""
    if not lost:
        return phases
    return {leg: LegPhases(tuple(sw for sw in ph.swings if not _touches(sw.t_up, sw.t_stop, lost, margin_s)),
                           tuple((a, b) for a, b in ph.leveling if not _touches(a, b, lost, margin_s)))
            for leg, ph in phases.items()}


READ_AGAIN_S = 0.1


def spans_between_lost(rec: Recording, legs) -> dict[int, list[tuple[float, float]]]:
    """Per leg, the spans of a stand recording between its lost spans: each starts once the joints of the
    leg read within ``READ_AGAIN_S`` of the gap's end have been read again (a replay starts from the latest
    read, which should not predate the gap); a joint read only later (a routine that moves one joint at a
    time) starts from its read before the gap, which the reads skipped at a segment's start cover)."""
    out = {}
    for leg in legs:
        reads = [rec.states[j].t_s for j in rec.states if j.leg == leg and len(rec.states[j])]
        cuts = [(0.0, 0.0)] + list(rec.lost) + [(rec.duration_s + 1.0, rec.duration_s + 1.0)]
        spans = []
        for (_, start), (end, _) in zip(cuts[:-1], cuts[1:]):
            firsts = [t[k] for t in reads for k in [np.searchsorted(t, start)] if k < len(t) and t[k] < end]
            soon = [t for t in firsts if t <= start + READ_AGAIN_S]
            a = max(soon) if soon else min(firsts, default=end)
            if end - a > 0.0:
                spans.append((float(a), min(end, rec.duration_s + 0.01)))
        out[leg] = spans
    return out


def swing_segments(rec: Recording, legs, lift_off_s: float = 0.08, before_stop_s: float = 0.1,
                   phases: dict | None = None, **kw) -> dict[int, list[tuple[float, float]]]:
    """Free-leg spans of every leg in a walk: from ``lift_off_s`` after the swing-up starts (the foot
    has left the ground) to ``before_stop_s`` before the swing-down stops (the detector stops the
    leg some tens of ms after touchdown). See docs/discrepancy.md for how both were measured."""
    phases = phases if phases is not None else gait_phases(rec, legs, **kw)
    out = {}
    for leg in legs:
        spans = []
        for sw in phases[leg].swings:
            a, b = sw.t_up + lift_off_s, sw.t_stop - before_stop_s
            if b - a > 0.05:
                spans.append((a, b))
        out[leg] = spans
    return out


def _overlap_s(spans, others) -> float:
    return sum(max(0.0, min(b, d) - max(a, c)) for a, b in spans for c, d in others)


def body_motion_share(phases: dict, segments: dict) -> float:
    """Share of the analysed swing time during which other legs' goals move (leveling: the stance legs
    move the body, which the free-leg model holds still); 0 for the cycle of Fig. 4 in sequence, about
    half for the overlapped cycle, where the leveling runs beside the next swing-up and swing-forward."""
    total = sum(b - a for spans in segments.values() for a, b in spans)
    if total <= 0:
        return 0.0
    moving = 0.0
    for leg, spans in segments.items():
        others = sorted(span for other, ph in phases.items() if other != leg for span in ph.leveling)
        # the union of the other legs' leveling spans, so overlapping ones count once
        union = []
        for a, b in others:
            if union and a <= union[-1][1]:
                union[-1][1] = max(union[-1][1], b)
            else:
                union.append([a, b])
        moving += _overlap_s(spans, union)
    return moving / total


def median_swing_up_s(phases: dict) -> float:
    """Median swing-up duration of the recorded swings [s] (nan without swings)."""
    d = [sw.t_forward - sw.t_up for ph in phases.values() for sw in ph.swings]
    return float(np.median(d)) if d else float('nan')


def _legs_swing_together(swings: dict, step_s: float = 0.01, share: float = 0.8) -> bool:
    """True if the legs' "swings" are one motion of every leg at once (more than ``share`` of the time
    any leg swings, all of them do): the stand calibration routine, not a gait, which always keeps
    legs on the ground. (A servo law unlike the model's sits the holding femurs off the prediction
    as a body's weight does: on a stand, 32 more punch made the femur test call the routine a walk.)"""
    legs = [spans for spans in swings.values() if spans]
    if len(legs) < 2:
        return False
    t_end = max(b for spans in legs for _a, b in spans)
    t = np.arange(0.0, t_end + step_s, step_s)
    up = np.zeros((len(legs), len(t)), dtype=bool)
    for i, spans in enumerate(legs):
        for a, b in spans:
            up[i] |= (t >= a) & (t <= b)
    anyone = np.count_nonzero(up.any(axis=0))
    return anyone > 0 and np.count_nonzero(up.all(axis=0)) > share * anyone


def looks_like_walk(replay, residual: dict, swings: dict, load_ticks: float = 1.0, min_reads: int = 10,
                    imu=None) -> bool:
    """True if femurs are pushed up outside their swing phases: the stance legs carry the body (and
    the legs do not all swing at once, :func:`_legs_swing_together`).

    ``residual``: read - nominal free-leg prediction per joint (whole recording); ``swings``: the
    swing spans of :func:`swing_segments`. On a stand a femur fits the free-leg model as well
    outside its swings as inside (effects such as friction or play spread both ways); in a walk
    the body's weight pushes every stance femur above the prediction (median over the reads outside
    the swings at least ``load_ticks`` above the median inside; a pentapod's stance femurs, with five
    legs sharing the weight, sit 0.5-2.5 ticks up in the default gait cycle, so 1.5 took some of its walks
    for stand recordings). A walk needs this on two femurs:
    a recording of one leg is never taken for a walk (a femur that cannot hold its goal, e.g. a
    torque limit on a stand, also sits off the prediction between its motions; ``--mode walk``
    forces the choice).

    Where the recording has ``/imu``, a body that rocks under the gait (:func:`body_moves`) is a walk as
    well: a servo law unlike the model's (much more damping, friction on every joint) moves a swinging
    femur off the prediction as much as a stance femur's load, and such walks failed the femur test.
    """
    if _legs_swing_together(swings) or sum(1 for spans in swings.values() if spans) < 2:
        return False
    return femur_votes(replay, residual, swings, load_ticks, min_reads)[0] >= 2 or body_moves(imu)


BODY_GYRO_RMS = 0.01     # [rad/s]: a body rocking faster than this (bias taken off) moves; see body_moves


def body_moves(imu) -> bool:
    """True if ``/imu`` shows the body rocking: the angular rate, its mean (the gyro's bias) taken off, at
    least ``BODY_GYRO_RMS`` RMS. The simulated walks of every gait and cycle rock it 0.033-0.21 rad/s RMS;
    a body at rest on a stand shows the gyro's noise (a MEMS gyro's is about 0.002 rad/s RMS at a 100 Hz
    bandwidth). False without an IMU (None) or with fewer than two samples."""
    if imu is None or len(imu) < 2:
        return False
    w = imu.gyro - imu.gyro.mean(axis=0)
    return float(np.sqrt(np.mean(np.sum(w * w, axis=1)))) >= BODY_GYRO_RMS


def walk_across_lost(replay, residual: dict, swings: dict, all_swings: dict, lost, settle_s: float = 0.3,
                     imu=None) -> bool | None:
    """:func:`looks_like_walk` on a recording with lost spans (``lost``, [s]), or None when it cannot tell.
    ``swings``: the swing spans clear of the lost spans; ``all_swings``: every swing the commands show;
    ``settle_s``: reads this soon after a lost span are not counted. Legs that swing
    together are a stand routine and femurs that carry load on two legs a walk, as on a whole recording;
    but femurs that do not show the load on the few swings left are no stand: a lost span takes the
    swings of a tripod with it, and with them half of the evidence (taken as a stand, a 2.5 s walk with
    0.18 s lost shows its stance legs' load as unexplained mismatches). A stand then needs commands without
    a single swing, or on one leg only (which, as on a whole recording, is never taken for a walk)."""
    if _legs_swing_together(all_swings) or sum(1 for spans in all_swings.values() if spans) < 2:
        return False
    # the replay restarts after each gap from the reads there, a stance leg's included: its load shows
    # only once the prediction has settled
    if femur_votes(replay, residual, swings, exclude=[(a, b + settle_s) for a, b in lost])[0] >= 2 or body_moves(imu):
        return True
    return None if any(all_swings.values()) else False


def femur_votes(replay, residual: dict, swings: dict, load_ticks: float = 1.0, min_reads: int = 10,
                exclude=()) -> tuple[int, int]:
    """(femurs pushed up outside their swings, femurs with enough reads inside and outside them to tell):
    the evidence :func:`looks_like_walk` weighs; reads in the ``exclude`` spans [s] are not counted."""
    femurs = [j for j in replay.joints if j.role == 'femur']
    hits = judged = 0
    for j in femurs:
        leg = j.leg
        spans = swings.get(leg) or []
        if not spans:
            continue
        t = replay.reads[j].t_s
        inside = np.zeros(len(t), dtype=bool)
        for a, b in spans:
            inside |= (t >= a) & (t <= b)
        counted = np.ones(len(t), dtype=bool)
        for a, b in exclude:
            counted &= (t < a) | (t > b)
        inside, outside = inside & counted, ~inside & counted
        if np.count_nonzero(inside) < min_reads or np.count_nonzero(outside) < min_reads:
            continue
        judged += 1
        r = residual[j]
        if np.median(r[outside]) - np.median(r[inside]) > load_ticks:
            hits += 1
    return hits, judged


def obstructed_swings(replay, residual: dict, settle_s: float = 0.1, factor: float = 3.0,
                      margin_ticks: float = 0.5) -> dict[int, list[int]]:
    """Swings in which something touched the leg: segment indices per leg to leave out.

    A foot that brushes a block edge during swing-forward departs from the free-leg model in that
    swing only, by several ticks, while a missing effect of the servo or the leg shows in every
    swing of the joint alike. A swing is obstructed when on any joint of its leg the RMS of
    ``residual`` (nominal model, reads at least ``settle_s`` after the segment start) exceeds
    ``factor`` times the median over that joint's other swings plus ``margin_ticks``; the swings of
    other legs at the same time are left out with it (the body they hang from was jolted).
    """
    out: dict[int, list[int]] = {}
    for leg in replay.legs:
        bad = set()
        for j in replay.joints:
            if j.leg != leg:
                continue
            r = replay.reads[j]
            starts = np.array([replay.segments[leg][i][0] * replay.dt for i in r.segment])
            ok = r.t_s >= starts + settle_s
            rms = {}
            for i in np.unique(r.segment[ok]):
                m = ok & (r.segment == i)
                rms[int(i)] = float(np.sqrt(np.mean(residual[j][m] ** 2)))
            if len(rms) < 2:
                continue
            for i, v in rms.items():      # against the median of the joint's other swings
                med = float(np.median([w for k, w in rms.items() if k != i]))
                if v > factor * med + margin_ticks:
                    bad.add(i)
        out[leg] = bad
    # what hits one leg jolts the body all swinging legs hang from: their concurrent swings go too
    hit = [replay.segments[leg][i] for leg, v in out.items() for i in v]
    for leg in replay.legs:
        for i, (ka, kb) in enumerate(replay.segments[leg]):
            if any(ka < hb and ha < kb for ha, hb in hit):
                out[leg].add(i)
    return {leg: sorted(v) for leg, v in out.items()}


# A walk's swing starts in motion from the reads around lift-off; reads in the first 0.1 s are left
# out of fit and judgement (on clean sim walks the nominal replay is at the rounding floor from there,
# docs/discrepancy.md).
WALK_SETTLE_S = 0.1


# What the walk analysis was measured on (docs/discrepancy.md, "Which walks"): a calibration walk,
# hexapod_locomotion/config/calibration_walk.yaml. Beyond these the nominal replay of a clean walk
# leaves more than tick rounding, and the report says why.
CALIBRATION_BODY_MOTION_SHARE = 0.1    # of the analysed swing time with the body moved by other legs
CALIBRATION_SWING_UP_S = 0.15          # swing-up duration [s]; the faster cycle in sequence left up to 0.96 ticks


def _body_motion_share(phases: dict, replay: Replay) -> float:
    """:func:`body_motion_share` over the replay's analysed swings (firmware periods -> s)."""
    return body_motion_share(phases, {leg: [(a * replay.dt, b * replay.dt) for a, b in v]
                                      for leg, v in replay.segments.items()})


def walk_replay(robot: Robot, rec: Recording, joints, segments, phases, step=lambda msg: None) -> Replay:
    """The swings of a walk, from lift-off, started in motion; where the body moves under them (other legs
    leveling) and the recording has ``/imu``, corrected by a replay with the body's motion
    (:mod:`.body_motion`). Not otherwise: the correction is a nominal replay added to every hypothesis, and
    on a calibration walk, where the body holds still, it took the coxa backlash of the walk bench from 20 %
    to 25 % off without lowering any clean walk's worst joint below 0.5 tick that was above it."""
    replay = Replay(robot, rec, joints=joints, segments=segments, moving_start=True)
    if rec.imu is not None and _body_motion_share(phases, replay) > CALIBRATION_BODY_MOTION_SHARE:
        step('replaying the swings with the body motion')
        replay.correction = body_motion_correction(replay, rec, robot)
    return replay


def walk_cycle_notes(phases: dict, replay: Replay) -> list[str]:
    """Notes on a walk whose gait cycle the free-leg replay is not measured for (without ``/imu``)."""
    if replay.correction is not None:
        return []
    out = []
    share = _body_motion_share(phases, replay)
    up = median_swing_up_s(phases)
    if share > CALIBRATION_BODY_MOTION_SHARE:
        out.append(f'the body moved under the swinging legs for {100 * share:.0f} % of the analysed swing time '
                   '(other legs leveling: the overlapped gait cycle); the free-leg model holds the body still, so '
                   'part of the mismatch may be body motion, not missing physics')
    if up < CALIBRATION_SWING_UP_S - 0.01:
        out.append(f'swing-ups of {1000 * up:.0f} ms, faster than the replay is measured for '
                   f'({1000 * CALIBRATION_SWING_UP_S:.0f} ms): fast swings shake the body on its stance legs')
    if out:
        out.append('for a walk this tool can judge to tick rounding, record a calibration walk: locomotion '
                   'parameters from hexapod_locomotion/config/calibration_walk.yaml (docs/discrepancy.md)')
    return out


def _walk_swings(rec: Recording, robot: Robot, joints, phases: dict, segs: dict, notes: list, step):
    """The replay of a walk's swings with the obstructed ones left out, its nominal prediction and residuals."""
    n_spans = sum(len(v) for v in segs.values())
    if n_spans == 0 and rec.lost:
        raise RecordingError(f'{rec.source}: {_lost_text(rec)}: no swing of the walk is left clear of them')
    if n_spans == 0:
        raise RecordingError(f'{rec.source}: looks like a walk (legs carry load) but no swing phase '
                             'was found in the femur commands; pass --time windows where the legs '
                             'hang free')
    step('replaying the swings')
    replay = walk_replay(robot, rec, joints, segs, phases, step)
    pred0 = replay.predict(robot)
    res0 = replay.residuals(pred0)
    blocked = obstructed_swings(replay, res0, settle_s=WALK_SETTLE_S)
    n_blocked = sum(len(v) for v in blocked.values())
    if n_blocked:
        spans = {leg: [(replay.segments[leg][i][0] * replay.dt, replay.segments[leg][i][1] * replay.dt)
                       for i in range(len(replay.segments[leg])) if i not in blocked.get(leg, ())]
                 for leg in replay.legs}
        where = '; '.join(f'leg {leg} at ' + ', '.join(f'{replay.segments[leg][i][0] * replay.dt:.1f} s'
                                                        for i in v)
                          for leg, v in blocked.items() if v)
        notes.append(f'{n_blocked} swing(s) left out as obstructed (the leg departs from the free-leg '
                     f'model in that swing only, e.g. a foot touching a block edge): {where}')
        replay = walk_replay(robot, rec, joints, spans, phases, step)
        pred0 = replay.predict(robot)
        res0 = replay.residuals(pred0)
    n_spans = sum(len(v) for v in replay.segments.values())
    total = sum(b - a for v in replay.segments.values() for a, b in v) * replay.dt
    notes.append(f'walk recording: stance legs carry the body, so only swing phases were analysed '
                 f'({n_spans} swings, {total:.1f} s of leg time, from lift-off to just before the '
                 f'swing-down stops, each started from the recorded position and speed)')
    if replay.correction is not None:
        notes.append('the body moved under the swinging legs: the swings were also replayed on the '
                     "MuJoCo hexapod with the trunk's acceleration and tilt from /imu, and the free-leg "
                     'model is corrected by that replay')
    notes.extend(walk_cycle_notes(phases, replay))
    return replay, pred0, res0


def _lost_text(rec: Recording) -> str:
    """What a damaged bag lost, in a few words."""
    spans = ', '.join(f'{a:.2f}-{b:.2f} s' for a, b in rec.lost[:4]) + (', ...' if len(rec.lost) > 4 else '')
    return (f'{len(rec.lost)} span(s) of the recording lost with damaged chunks ({rec.lost_s:.2f} s of '
            f'{rec.duration_s:.1f} s: {spans})')


def replay_analysed(rec: Recording, robot: Robot, joints, windows, mode: str, notes: list, step):
    """The replay the analysis judges: the given windows, a walk's swings or the whole stand.
    -> (replay, nominal prediction, residuals, gait phases or None, mode used, reads skipped at a segment's
    start [s])."""
    segments, mode_used = None, mode
    if windows:
        legs_all = sorted({j.leg for j in rec.joints})
        segments = {leg: list(windows) for leg in legs_all}
        mode_used = 'windows'
        notes.append('analysed only the given time windows: '
                     + ', '.join(f'{a:g}-{b:g} s' for a, b in windows))
    elif rec.lost:                     # a damaged bag: nothing is replayed across a lost span
        segments = spans_between_lost(rec, sorted({j.leg for j in rec.joints}))
    step('replaying the recorded goals')
    replay = Replay(robot, rec, joints=joints, segments=segments)
    pred0 = replay.predict(robot)
    res0 = replay.residuals(pred0)
    phases = None
    skip_start_s = 0.3
    if mode_used != 'windows':
        every = gait_phases(rec, replay.legs)
        phases = clear_of_lost(every, rec.lost)
        segs = swing_segments(rec, replay.legs, phases=phases)
        verdict = mode == 'walk'
        if mode == 'auto':
            verdict = walk_across_lost(replay, res0, segs, swing_segments(rec, replay.legs, phases=every), rec.lost,
                                       skip_start_s, imu=rec.imu) if rec.lost else looks_like_walk(
                                           replay, res0, segs, imu=rec.imu)
        if verdict is None and rec.lost:
            raise RecordingError(f'{rec.source}: {_lost_text(rec)}: what is left does not tell a walk from a '
                                 'stand (--mode walk or --mode stand decides)')
        if verdict:
            replay, pred0, res0 = _walk_swings(rec, robot, joints, phases, segs, notes, step)
            skip_start_s = WALK_SETTLE_S
            mode_used = 'walk'
        else:
            mode_used = 'stand'
            notes.append('stand recording: every leg treated as hanging free for the whole recording'
                         + (' (apart from the lost spans)' if rec.lost else ''))
    if rec.lost:
        notes.append(f'{_lost_text(rec)}: left out' + (', with every swing within '
                                                        f'{LOST_MARGIN_S:g} s of one' if mode_used == 'walk' else ''))
    return replay, pred0, res0, phases, mode_used, skip_start_s
