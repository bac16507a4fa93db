"""Step 3, name: which candidate effect, on which joints, with which parameter explains the mismatch.

Hypotheses are (effect, joints) pairs with one shared physical parameter: every single joint,
every leg (its three joints) and the whole robot (every analysed joint); a payload
(``mass_error``) belongs to a leg or to every leg. The search is greedy forward selection:

1. *Screen* every hypothesis cheaply: one rollout per (effect, joint) at a probe magnitude
   gives the effect's signature ``D`` (change of every prediction); a least-squares scale
   ``alpha`` of ``D`` against the current residual on the fitting reads predicts the gain on
   the held-out reads. Strongly nonlinear effects are probed at three magnitudes, static
   friction once per band between two firmware torque levels (:meth:`Namer._probes`).
2. *Fit* the most promising hypotheses exactly (:meth:`Namer.fit`), with the full nonlinear
   rollout, so friction, backlash, dead-band and saturation are fitted as what they are. The
   residual is piecewise smooth in the parameter (integer ticks in the firmware) and, where a
   joint hunts in a limit cycle, rugged; so the parameter is found by grids and bounded 1-D
   searches (:func:`scipy.optimize.minimize_scalar`, Brent), first on a phase-insensitive
   windowed loss that locates the basin, then on the pointwise squared residual of the fitting
   reads of every joint the effect touches.
3. *Judge* on held-out reads only (alternating time blocks never used for fitting): a hypothesis
   is accepted when it lowers the held-out RMS error on its joints by at least
   ``min_ratio`` (default 1.15x) and ``min_drop_ticks``, explains at least half of the held-out
   variance above tick rounding (a small dent in a misfit the model cannot describe, e.g. feet
   touching the ground, is no effect), lowers the held-out squared error by ``min_gain_ticks2`` in
   all (a handful of reads is no confirmation), and its parameter is not stuck at an end of its plausible
   range. The accepted hypothesis with the largest held-out gain wins; a smaller
   scope that achieves nearly the same gain (``parsimony``) is preferred, unless the joints only
   the larger scope reaches confirm the effect on their own held-out reads by the same test
   (a joint with few reads adds little gain however clearly it shows the effect). A joint effect on
   several joints that makes one of them clearly worse held out (``WORSE_TICKS``) is not that scope; an
   effect screened best on several joints is also fitted on its best single joint, since the screen credits
   a larger scope with whatever its extra joints share with the signature. Repeat with the effect
   added to the model, until nothing passes (``max_effects``).
4. With several effects, every parameter is refitted once with the others in place, and a joint effect
   that shares joints with others is dropped where they, fitted again without it, predict the held-out
   reads at least as well (:meth:`Namer.without_redundant`).

The servo law's terms (punch, motor damping, goal latency: :mod:`.effects`) are hypotheses on the
whole robot only; when one passes alone in a round, all of them are fitted at once
(:meth:`Namer._servo_law_bundle`), since fitted in turn the first takes what belongs to the others.
The analysis then names an effect only where it explains most of its joints' excess over tick
rounding with the others in place (``min_final_explained``; see :mod:`.analysis`).

The predictions, the fit / held-out split of the reads and what a recording cannot show are
:mod:`.predict`'s.

Noise-fitting is not rewarded: parameters never see the held-out reads, and a gain that the
held-out reads do not confirm by a clear factor is not an effect. An empty result means "no
missing physics found".
"""
from __future__ import annotations

import math

import numpy as np
from scipy.optimize import minimize_scalar

from hexapod_model.description import Effect, Robot
from hexapod_model.joints import LEG_JOINTS, Joint
from hexapod_sim.discrepancy.effects import BY_NAME, Candidate
from hexapod_sim.discrepancy.hypothesis import FitSettings, Hypothesis
from hexapod_sim.discrepancy.predict import ROUNDING_VAR, Predictor, Split, affected_joints, effect_units
from hexapod_sim.discrepancy.servo_law_search import ServoLawSearch
from hexapod_sim.discrepancy.simulate import Replay

NONLINEAR = ('static_friction', 'backlash', 'compliance_deadband', 'torque_saturation')
# A joint effect that, put on every analysed joint, is a servo-law term the tool names as such: on the
# whole robot the servo law's candidate stands for it (the replay cannot tell them apart).
ROBOT_WIDE_AS = {'viscous_damping': 'motor_damping', 'readout_delay': 'goal_latency'}
TWIN_OF = {law: joint_effect for joint_effect, law in ROBOT_WIDE_AS.items()}
# A twin joint effect named beside its servo-law term, or an effect named on some joints of a larger effect
# of its kind, at less than this share of that term's or effect's size (a servo-law term as the twin's
# parameter, :func:`as_twin`) is the larger one fitted unevenly over its joints, not physics of its own
# (robot-wide viscous damping of 0.187 N m s/rad fitted as 1.85x motor damping, 0.172, left 0.015 on two
# legs; a leg's 0.193 fitted as 0.166 left 0.023 on its femur).
UNEVEN_SHARE = 0.25
# A joint effect on several joints that raises one joint's held-out RMS error by more than this [ticks]
# is not on that joint (a leg-wide dead-band that takes a coxa at rounding, 0.32, to 0.83 ticks).
WORSE_TICKS = 0.2


def as_twin(law: Effect, robot: Robot) -> float:
    """A servo-law term as the parameter of its twin joint effect (:data:`TWIN_OF`) on every joint: motor
    damping as the extra viscous damping it adds, a goal latency as the readout delay it looks like."""
    if law.effect == 'motor_damping':
        return (law.params['ratio'] - 1.0) * robot.servo.reflected_damping_nms_per_rad
    return law.params['delay_s']


def law_of_twins(twins, robot: Robot, joints) -> Effect | None:
    """The servo-law term on ``joints`` whose twin (:data:`TWIN_OF`) the joint effects ``twins`` are, at
    their median value (the inverse of :func:`as_twin`; the kind most of them are); None without twins."""
    kinds = [e.effect for e in twins if e.effect in ROBOT_WIDE_AS]
    if not kinds:
        return None
    kind = max(set(kinds), key=kinds.count)
    value = float(np.median([e.params[BY_NAME[kind].key] for e in twins if e.effect == kind]))
    law = ROBOT_WIDE_AS[kind]
    if law == 'motor_damping':
        value = 1.0 + value / robot.servo.reflected_damping_nms_per_rad
    return BY_NAME[law].make(tuple(joints), value)


def uneven_parts(effects, robot: Robot) -> list[int]:
    """Indices of the effects in ``effects`` that are a larger one fitted unevenly (:data:`UNEVEN_SHARE`):
    a servo-law term's twin, or an effect of the same kind on some of another's joints."""
    out = []
    for big in effects:
        if big.effect in TWIN_OF:
            kind, size = TWIN_OF[big.effect], abs(as_twin(big, robot))
        elif big.effect in BY_NAME and not BY_NAME[big.effect].servo_law:
            kind, size = big.effect, abs(big.params[BY_NAME[big.effect].key])
        else:
            continue
        key = BY_NAME[kind].key
        out.extend(i for i, e in enumerate(effects)
                   if e is not big and e.effect == kind and abs(e.params[key]) < UNEVEN_SHARE * size
                   and (big.effect in TWIN_OF or set(e.joints) <= set(big.joints)))
    return sorted(set(out))


class Namer(ServoLawSearch):
    """Greedy forward selection of effects (see the module docstring)."""

    def __init__(self, replay: Replay, base: Robot, split: Split, settings: FitSettings | None = None,
                 progress=None, workers: int = 2):
        self.rep = replay
        self.split = split
        self.s = settings or FitSettings()
        self.base = base
        self.pred = Predictor(replay, base, workers=workers)
        self.meas = {j: replay.reads[j].tick for j in replay.joints}
        self.progress = progress
        self._prepare_features()
        unknown = [c for c in self.s.candidates if c not in BY_NAME]
        if unknown:
            raise ValueError(f'unknown candidate effect(s) {unknown}; known: {sorted(BY_NAME)}')

    def close(self):
        self.pred.close()

    # ------------------------------------------------------------------ helpers
    def _sse(self, pred: dict, joints, which: str) -> tuple[float, int]:
        masks = self.split.fit if which == 'fit' else self.split.hold
        sse, n = 0.0, 0
        for j in joints:
            if j not in pred:
                continue
            m = masks[j]
            d = self.meas[j][m] - pred[j][m]
            sse += float(d @ d)
            n += int(np.count_nonzero(m))
        return sse, n

    def _probes(self, c: Candidate) -> tuple[float, ...]:
        """Magnitudes at which the screen probes candidate ``c``.

        Strongly nonlinear effects are probed at half, one and two times their typical magnitude;
        the others at the typical one. Static friction decides stick or slip by comparing the
        break-away torque with the firmware's torque, which takes one value per integer error
        (gain x (error - margin)): on a joint without gravity load (a coxa) every break-away torque
        between two of those levels gives the same motion, and three probes can all miss the band
        that holds the truth (0.153 N m on a coxa lies between the 3- and 4-tick levels, 0.141 and
        0.188 N m; the probes 0.1, 0.2, 0.4 N m matched nothing there). So static friction is probed
        once per band, at its middle, over the plausible range.
        """
        if c.effect == 'static_friction':
            s = self.base.servo
            g, m, pn = s.gain_nm_per_tick, s.compliance_margin_ticks, s.punch_nm
            # levels pn + g (k - m) for k > m; probe the middle of every band between two of them
            k = np.arange(math.ceil((c.lo - pn) / g + m - 0.5), math.floor((c.hi - pn) / g + m - 0.5) + 1)
            return tuple(float(v) for v in pn + g * (k - m + 0.5))
        if c.effect in NONLINEAR:
            return (0.5 * c.typical, c.typical, 2.0 * c.typical)
        if c.two_sided:            # a ratio: its nominal 1 lies inside the range, so probe both ways
            return (1.0 / c.typical, c.typical)
        return (c.typical,)

    def _hypotheses(self) -> list[Hypothesis]:
        joints = self.rep.joints
        legs = sorted({j.leg for j in joints})
        out = []
        for name in self.s.candidates:
            c = BY_NAME[name]
            if c.servo_law:               # the same firmware on every servo: the whole robot only
                if len(joints) > 1:
                    out.append(Hypothesis(c, tuple(joints)))
                continue
            if not c.leg_only:
                out.extend(Hypothesis(c, (j,)) for j in joints)
            for leg in legs:
                lj = tuple(j for j in LEG_JOINTS[leg] if j in joints)
                if len(lj) > 1 or c.leg_only:
                    out.append(Hypothesis(c, lj))
            if len(legs) > 1:
                out.append(Hypothesis(c, tuple(joints)))
        # on every analysed joint, viscous damping is the motor damping and a readout delay the goal
        # latency of the servo law: the servo law's candidate is the one named
        every = set(joints)
        out = [h for h in out if not (len(every) > 1 and set(h.joints) == every
                                      and ROBOT_WIDE_AS.get(h.candidate.effect) in self.s.candidates)]
        # drop duplicates (a leg with one analysed joint equals the joint hypothesis)
        seen, uniq = set(), []
        for h in out:
            k = (h.candidate.effect, h.joints)
            if k not in seen:
                seen.add(k)
                uniq.append(h)
        return uniq

    # ------------------------------------------------------------------ screening
    def screen(self, effects, base_pred) -> list[Hypothesis]:
        """Linearised gain of every hypothesis: the signature ``D`` of an effect (change of every
        prediction at a probe magnitude) scaled by least squares against the residual.

        Strongly nonlinear effects (stick-slip, play, dead-band, saturation) are probed at half,
        one and two times their typical magnitude and the best probe counts. Signatures are only
        computed on joints whose fitting or held-out residual is above ``screen_floor_ticks`` (elsewhere there
        is nothing to explain; their share of a hypothesis counts as zero here and is judged by
        the exact fit).
        """
        joints = self.rep.joints
        active = set()
        for j in joints:
            # above the floor on the fitting or the held-out reads (which the screen predicts the gain
            # on): a break-away that shows in a few holds can fall in held-out blocks only
            for mask in (self.split.fit[j], self.split.hold[j]):
                r = (self.meas[j] - base_pred[j])[mask]
                if len(r) and math.sqrt(float(r @ r) / len(r)) > self.s.screen_floor_ticks:
                    active.add(j)
        sig: dict[tuple, dict[Joint, np.ndarray]] = {}
        for name in self.s.candidates:
            c = BY_NAME[name]
            mags = self._probes(c)
            for key_joint, on in effect_units(c, joints):
                aff = sorted(affected_joints(c.effect, on) & active)
                if not aff:
                    continue
                for m, mag in enumerate(mags):
                    p = self.pred.predict(tuple(effects) + (c.make(on, mag),), aff)
                    sig[(c.effect, key_joint, m)] = {a: p[a] - base_pred[a] for a in aff}
        hyps = self._hypotheses()
        fitm, holdm = self.split.fit, self.split.hold
        for h in hyps:
            c = h.candidate
            if c.servo_law:
                members = [h.joints[0]]
            elif c.leg_only:
                members = list(dict.fromkeys(LEG_JOINTS[j.leg][0] for j in h.joints))
            else:
                members = list(h.joints)
            for m in range(len(self._probes(c))):
                D: dict[Joint, np.ndarray] = {}
                for mj in members:
                    for a, d in sig.get((c.effect, mj, m), {}).items():
                        D[a] = D[a] + d if a in D else d
                num = den = before = gain = 0.0
                for a, d in D.items():
                    r = self.meas[a] - base_pred[a]
                    k = fitm[a]
                    num += float(r[k] @ d[k])
                    den += float(d[k] @ d[k])
                if den <= 0:
                    continue
                alpha = max(num / den, 0.0)       # effects have a fixed sign: a negative scale means "not this"
                for a, d in D.items():
                    r = self.meas[a] - base_pred[a]
                    k = holdm[a]
                    before += float(r[k] @ r[k])
                    gain += float(r[k] @ r[k]) - float((r[k] - alpha * d[k]) @ (r[k] - alpha * d[k]))
                if gain > h.screen_gain:
                    h.screen_gain = gain
                    h.screen_ratio = math.sqrt(before / max(before - gain, 1e-12)) if before > 0 else 1.0
        return hyps

    # ------------------------------------------------------------------ exact fit
    def _feature_sse(self, pred: dict, joints) -> float:
        """Phase-insensitive loss: per window of ``feature_window_s``, squared difference of the mean
        and of the spread of ``position - goal`` (recorded vs predicted), weighted by the read count."""
        out = 0.0
        for j in joints:
            if j not in pred:
                continue
            win, g, cnt, mu_m, sd_m = self._feat[j]
            d = pred[j][self.split.fit[j]] - g
            nw = len(cnt)
            mu = np.bincount(win, d, nw) / np.maximum(cnt, 1)
            sd = np.sqrt(np.maximum(np.bincount(win, d * d, nw) / np.maximum(cnt, 1) - mu * mu, 0.0))
            out += float(np.sum(cnt * ((mu_m - mu) ** 2 + (sd_m - sd) ** 2)))
        return out

    def _prepare_features(self):
        self._feat = {}
        for j in self.rep.joints:
            r = self.rep.reads[j]
            m = self.split.fit[j]
            k = np.clip(np.floor(r.t_s[m] / self.rep.dt + 1e-9).astype(np.int64), 0, self.rep.n_periods - 1)
            g = self.rep.goals[j][k]
            win_raw = np.floor(r.t_s[m] / self.s.feature_window_s).astype(np.int64)
            _, win = np.unique(win_raw, return_inverse=True)
            nw = int(win.max()) + 1 if len(win) else 0
            cnt = np.bincount(win, minlength=nw).astype(float)
            d = self.meas[j][m] - g
            mu = np.bincount(win, d, nw) / np.maximum(cnt, 1)
            sd = np.sqrt(np.maximum(np.bincount(win, d * d, nw) / np.maximum(cnt, 1) - mu * mu, 0.0))
            self._feat[j] = (win, g, cnt, mu, sd)

    def fit(self, h: Hypothesis, effects, base_pred) -> Hypothesis:
        """Fit the hypothesis' parameter (see the module docstring).

        Stage 1 locates the basin with the phase-insensitive windowed loss (smooth even when the
        joint hunts in a limit cycle, e.g. with backlash and no gravity preload): geometric grid,
        then bounded Brent. Stage 2 minimises the pointwise squared residual in a +-15 % band around
        it (dense local grid, then bounded Brent): the parameter that best predicts every read.
        """
        c = h.candidate
        aff = self._score_before(h, base_pred)
        cache: dict[float, tuple[float, float]] = {}

        def evaluate(v: float) -> tuple[float, float]:
            v = float(v)
            if v not in cache:
                p = self.pred.predict(tuple(effects) + (c.make(h.joints, v),), aff)
                cache[v] = (self._sse(p, aff, 'fit')[0], self._feature_sse(p, aff))
                h.evals += 1
            return cache[v]

        grid = np.geomspace(c.lo, c.hi, self.s.grid)
        feat = [evaluate(v)[1] for v in grid]
        i = int(np.argmin(feat))
        a, b = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
        res = minimize_scalar(lambda v: evaluate(v)[1], bounds=(a, b), method='bounded',
                              options={'xatol': 0.01 * grid[i], 'maxiter': 10})
        v1 = min((v for v in cache if a <= v <= b), key=lambda v: cache[v][1])
        if res.success and evaluate(res.x)[1] <= cache[v1][1]:
            v1 = float(res.x)
        lo_b, hi_b = max(c.lo, v1 / 1.15), min(c.hi, v1 * 1.15)
        # stick-slip and play make the pointwise loss rugged (resting ticks flip with the parameter):
        # a dense local grid for a few joints (cheap), a coarser one where many joints average it out
        for v in np.geomspace(lo_b, hi_b, 15 if len(aff) <= 3 else 7):
            evaluate(v)
        near = sorted(v for v in cache if lo_b <= v <= hi_b)
        v2 = min(near, key=lambda v: cache[v][0])
        k = near.index(v2)
        a2, b2 = near[max(k - 1, 0)], near[min(k + 1, len(near) - 1)]
        if b2 > a2:
            res = minimize_scalar(lambda v: evaluate(v)[0], bounds=(a2, b2), method='bounded',
                                  options={'xatol': 0.002 * v2, 'maxiter': 6})
            if res.success and evaluate(res.x)[0] < cache[v2][0]:
                v2 = float(res.x)
        h.value = float(v2)
        h.fit_sse_after = cache[v2][0]
        self._score_held_out(h, effects, base_pred, aff)
        return h

    def _score_before(self, h: Hypothesis, base_pred) -> list[Joint]:
        """``h``'s affected joints and its fitting and held-out errors under ``base_pred``; the joints."""
        aff = sorted(affected_joints(h.candidate.effect, h.joints) & set(self.rep.joints))
        h.affected = tuple(aff)
        h.fit_sse_before, _ = self._sse(base_pred, aff, 'fit')
        h.hold_sse_before, h.n_hold = self._sse(base_pred, aff, 'hold')
        return aff

    def _score_held_out(self, h: Hypothesis, effects, base_pred, aff) -> dict:
        """``h``'s held-out errors at its value with ``effects`` in place (all and per joint); the prediction."""
        p = self.pred.predict(tuple(effects) + (h.effect,), aff)
        h.hold_sse_after, _ = self._sse(p, aff, 'hold')
        for j in aff:
            b, n = self._sse(base_pred, (j,), 'hold')
            h.hold_by_joint[j] = (b, self._sse(p, (j,), 'hold')[0], n)
        return p

    def passes(self, h: Hypothesis) -> bool:
        c = h.candidate
        if not np.isfinite(h.value) or h.n_hold == 0:
            return False
        # a parameter at either end of its plausible range is not a physical explanation
        for end in (c.lo, c.hi):
            if abs(h.value - end) <= 0.02 * abs(end) + 1e-12:
                return False
        return (self._confirms(h.hold_sse_before, h.hold_sse_after, h.n_hold)
                and h.fit_sse_after < h.fit_sse_before)

    def _confirms(self, sse_before: float, sse_after: float, n: int, share: bool = True) -> bool:
        """The held-out acceptance test on ``n`` reads: ratio, drop, explained share and total gain
        (``share`` False: ratio and drop only)."""
        if n == 0:
            return False
        before, after = math.sqrt(sse_before / n), math.sqrt(sse_after / n)
        excess = before ** 2 - ROUNDING_VAR
        explained = (before ** 2 - after ** 2) / excess if excess > 0 else 0.0
        return (after > 0 and before / after >= self.s.min_ratio and before - after >= self.s.min_drop_ticks
                and (not share or (explained >= self.s.min_explained
                                   and sse_before - sse_after >= self.s.min_gain_ticks2)))

    def _worsens_a_joint(self, h: Hypothesis) -> bool:
        """Whether a joint effect on several joints makes one of them clearly worse on its held-out
        reads: the effect is not on that joint, so this is not its scope (the servo law's terms are on
        every servo whatever a joint shows, and are not judged so)."""
        if h.candidate.servo_law or len(h.joints) < 2:
            return False
        return any(n and math.sqrt(a / n) - math.sqrt(b / n) > WORSE_TICKS
                   for b, a, n in h.hold_by_joint.values())

    def _extra_joints_confirm(self, big: Hypothesis, small: Hypothesis) -> bool:
        """Whether the joints only the larger scope ``big`` reaches (those whose predictions ``small``
        leaves unchanged) confirm the effect on their own held-out reads, by the acceptance test.
        Parsimony weighs gains in squared ticks, so a joint read rarely (a walking coxa: 18 reads a
        swing beside a femur's 300) hardly counts there, however clearly its reads show the effect."""
        extra = [j for j in big.affected if j not in small.affected]
        b = sum(big.hold_by_joint[j][0] for j in extra)
        a = sum(big.hold_by_joint[j][1] for j in extra)
        n = sum(big.hold_by_joint[j][2] for j in extra)
        return self._confirms(b, a, n)

    # ------------------------------------------------------------------ the search
    def run(self, given=()) -> tuple[list[Effect], list[Hypothesis]]:
        """The effects named and their hypotheses; ``given``: effects in place throughout, not named again."""
        effects: list[Effect] = list(given)
        accepted: list[Hypothesis] = []
        for round_ in range(self.s.max_effects):
            base_pred = self.pred.predict(effects, self.rep.joints)
            done = {(h.candidate.effect, h.joints) for h in accepted}
            hyps = [h for h in self.screen(effects, base_pred) if (h.candidate.effect, h.joints) not in done]
            hyps = [h for h in hyps if h.screen_gain > 0 and h.screen_ratio >= self.s.min_screen_ratio]
            # near-ties go to the smaller scope (joints at the rounding floor add nothing to a screen)
            hyps.sort(key=lambda h: -h.screen_gain * (1.0 - 0.01 * math.log2(len(h.joints))))
            picked = self._pick_for_fit(hyps)
            fitted = []
            for h in picked:
                self.fit(h, effects, base_pred)
                fitted.append(h)
                self.s.log.append(('round', round_, h.candidate.effect, h.joints, h.value, h.hold_rmse_before,
                                   h.hold_rmse_after, h.screen_gain, self.passes(h)))
                if self.progress is not None:
                    self.progress(f'round {round_ + 1}: {h.candidate.effect} on {len(h.joints)} joint(s)')
            ok = [h for h in fitted if self.passes(h) and not self._worsens_a_joint(h)]
            bundle, bundle_gain = self._servo_law_bundle(effects, base_pred, fitted)
            best = max(ok, key=lambda h: h.hold_gain) if ok else None
            if best is not None and best.candidate.servo_law:
                # a servo-law term whose joint-effect twin on fewer joints gains nearly as much: the
                # others do not show it, so it is that joint effect (a readout delay of one tibia)
                best = self._smaller_scope(best, ok, TWIN_OF.get(best.candidate.effect))
            # the servo law's terms together: where none passes alone, or where they gain more than the best
            if bundle and (best is None or ((len(bundle) > 1 or best.candidate.servo_law)
                                            and bundle_gain >= best.hold_gain)):
                for h in bundle:
                    effects.append(h.effect)
                    accepted.append(h)
                    self.s.log.append(('servo_law', round_, h.candidate.effect, h.value))
                continue
            if best is None:
                pair = self._with_servo_law(effects, base_pred, fitted)
                if not pair:
                    break
                for h in pair:
                    effects.append(h.effect)
                    accepted.append(h)
                    self.s.log.append(('pair', round_, h.candidate.effect, h.joints, h.value))
                continue
            best = self._smaller_scope(best, ok, best.candidate.effect)
            effects.append(best.effect)
            accepted.append(best)
        if len(accepted) > 1:
            accepted = self.without_redundant(self.refine(accepted, given), given)
        return [h.effect for h in accepted], accepted

    def _smaller_scope(self, best: Hypothesis, ok: list[Hypothesis], effect: str | None) -> Hypothesis:
        """The smallest accepted hypothesis of ``effect`` on a subset of ``best``'s joints that reaches
        ``parsimony`` of its held-out gain, unless the joints only ``best`` reaches confirm it on their own;
        else ``best``."""
        for h in sorted(ok, key=lambda h: len(h.joints)):
            if (h.candidate.effect == effect and set(h.joints) < set(best.joints)
                    and h.hold_gain >= self.s.parsimony * best.hold_gain
                    and not self._extra_joints_confirm(best, h)):
                return h
        return best

    def _pick_for_fit(self, hyps: list[Hypothesis]) -> list[Hypothesis]:
        """The best screened hypotheses, at most two per effect, ``n_fit`` in all. Where an effect's best
        is on several joints, its second is the best on one of those joints: the screen credits a larger
        scope with whatever its extra joints' residuals share with the signature (a tibia's readout
        delay with a dead-band beside it on the femur), and only the exact fit tells them apart."""
        per_effect: dict[str, list[Hypothesis]] = {}
        out = []
        for h in hyps:
            mine = per_effect.setdefault(h.candidate.effect, [])
            if len(mine) >= 2:
                continue
            if len(mine) == 1 and len(mine[0].joints) > 1:
                h = next((s for s in hyps if s.candidate.effect == h.candidate.effect and len(s.joints) == 1
                          and s.joints[0] in mine[0].joints), h)
            mine.append(h)
            out.append(h)
            if len(out) >= self.s.n_fit:
                break
        return out

    def without_redundant(self, accepted: list[Hypothesis], given=()) -> list[Hypothesis]:
        """``accepted`` without a joint effect that shares joints with other joint effects where those,
        fitted again without it (their basin searched anew), predict the held-out reads of the joints
        they touch at least as well: two effects on one joint can settle in a basin of their own (an 8 ms
        readout delay on a femur, fitted at 2.8 ms before the servo law's punch was named, stayed at 3.5 ms
        with a Coulomb friction of 0.047 N m beside it, 0.41 ticks held out; the delay alone, fitted
        again beside the punch, 7.8 ms and 0.33 ticks)."""
        out = list(accepted)
        i = 0
        while i < len(out):
            h = out[i]
            peers = [x for x in out if x is not h and set(h.joints) & set(x.joints) and not x.candidate.servo_law]
            if h.candidate.servo_law or not peers:
                i += 1
                continue
            rest = [x for x in out if x is not h]
            for k, x in enumerate(rest):
                if any(x is p for p in peers):
                    others = list(given) + [y.effect for y in rest if y is not x]
                    rest[k] = self.fit(Hypothesis(x.candidate, x.joints), others,
                                       self.pred.predict(others, self.rep.joints))
            joints = sorted(set().union(*(affected_joints(y.candidate.effect, y.joints) for y in [h] + peers))
                            & set(self.rep.joints))
            now, _ = self._sse(self.pred.predict(list(given) + [y.effect for y in out], joints), joints, 'hold')
            then, _ = self._sse(self.pred.predict(list(given) + [y.effect for y in rest], joints), joints, 'hold')
            if then <= now:
                self.s.log.append(('redundant', h.candidate.effect, h.joints, h.value))
                out, i = rest, 0
            else:
                i += 1
        return out

    def refine(self, accepted: list[Hypothesis], given=()) -> list[Hypothesis]:
        """Refit each parameter once with all other accepted effects (and ``given``) in place."""
        out = list(accepted)
        for i, h in enumerate(out):
            others = list(given) + [x.effect for k, x in enumerate(out) if k != i]
            base_pred = self.pred.predict(others, self.rep.joints)
            nh = Hypothesis(h.candidate, h.joints)
            self.fit(nh, others, base_pred)
            out[i] = nh
        return out
