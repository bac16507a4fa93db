"""The servo law's terms in the namer (:class:`.fit.Namer`): fitted together, and beside a joint effect.

Punch, motor damping and goal latency act on every servo at once, so the namer fits them on the whole
robot only, together where one of them alone improves the recording, and in a pair with a joint effect
where neither passes alone.
"""
from __future__ import annotations

import math

import numpy as np

from hexapod_sim.discrepancy.effects import BY_NAME
from hexapod_sim.discrepancy.hypothesis import Hypothesis
from hexapod_sim.discrepancy.predict import affected_joints

# joint effects fitted beside a servo-law term that passes only with one of them (_with_servo_law)
PAIR_TRIES = 3
PAIR_ROUNDS = 4        # and the pair's parameters are fitted in turn at most this often (_alternate)
PAIR_SETTLED = 0.05    # until the servo-law term's changes by less than this share
NEEDED_REFITS = 3      # the others refitted this often without a servo-law term (servo_law_needed)


class ServoLawSearch:
    """The servo-law steps of :class:`.fit.Namer`'s search (it provides ``rep``, ``s``, ``pred``, ``fit``,
    ``passes``, ``_confirms``, ``_sse``, ``_score_before``, ``_score_held_out`` and ``_worsens_a_joint``)."""

    def _with_servo_law(self, effects, base_pred, fitted: list[Hypothesis]) -> list[Hypothesis]:
        """A servo-law term and a joint effect that pass only together, when nothing passes alone.

        A servo-law term acts on every joint, so beside a joint effect it explains less than half of
        that joint's excess and fails the explained share (0.15 N m more punch than the model has, beside
        a 3-tick dead-band on a tibia, on a one-leg stand: punch alone 1.97 -> 1.62 ticks held out, 33 %
        of the excess), and the joint effect alone fails as well, its joint carrying the punch too. So
        where a servo-law term's fit clears the ratio and the drop of the acceptance test, the best
        screened joint effects of the round are fitted with it in place, and it is refitted with each
        that then passes: the pair is taken when both pass with the other in place. -> [servo-law term, joint effect] or []."""
        near = [h for h in fitted if h.candidate.servo_law and np.isfinite(h.value) and h.n_hold
                and h.fit_sse_after < h.fit_sse_before
                and self._confirms(h.hold_sse_before, h.hold_sse_after, h.n_hold, share=False)]
        if not near:
            return []
        law = max(near, key=lambda h: h.hold_gain)
        with_law = list(effects) + [law.effect]
        base_law = self.pred.predict(with_law, self.rep.joints)
        for h in [h for h in fitted if not h.candidate.servo_law][:PAIR_TRIES]:
            joint = self.fit(Hypothesis(h.candidate, h.joints), with_law, base_law)
            if not self.passes(joint) or self._worsens_a_joint(joint):
                continue
            law2, joint = self._alternate(effects, law, joint)
            if self.passes(law2) and self.passes(joint):
                return [law2, joint]
        return []

    def _alternate(self, effects, law: Hypothesis, joint: Hypothesis) -> tuple[Hypothesis, Hypothesis]:
        """The pair's parameters fitted in turn, each with the other in place, until the servo-law term's
        changes by less than ``PAIR_SETTLED`` (at most ``PAIR_ROUNDS`` times): fitted once each, the
        first takes part of the other's share (the punch of the dead-band case above: 0.103 N m of 0.149
        after one turn, with the dead-band at 3.02 ticks of 3)."""
        for _ in range(PAIR_ROUNDS):
            with_joint = list(effects) + [joint.effect]
            new_law = self.fit(Hypothesis(law.candidate, law.joints), with_joint,
                               self.pred.predict(with_joint, self.rep.joints))
            settled = abs(new_law.value - law.value) <= PAIR_SETTLED * abs(law.value)
            law = new_law
            with_law = list(effects) + [law.effect]
            joint = self.fit(Hypothesis(joint.candidate, joint.joints), with_law,
                             self.pred.predict(with_law, self.rep.joints))
            if settled or not np.isfinite(law.value):
                break
        return law, joint

    def _servo_law_bundle(self, effects, base_pred, fitted: list[Hypothesis]) -> tuple[list[Hypothesis], float]:
        """The servo-law terms that together explain the recording, when one of them improves it alone.

        Punch, motor damping and goal latency act on every servo at once and partly stand in for each
        other (more punch speeds a move up where more damping slows it down), so one of them alone can
        lose to a joint effect that mimics their sum (a torque limit on the whole robot), and fitted one
        after the other the first takes what belongs to the others (a walk with 1.15x damping, more punch
        and a 1 ms goal latency: damping 1.07 alone, then no punch), or none passes alone (a tetrapod walk
        with 0.14 N m more punch and 1.3x damping: punch alone explained 31 % of the excess, a leg's torque
        limit was taken instead). So when a servo-law term's fit improves the held-out reads at all, all of
        them are fitted at once (Nelder-Mead on the fitting reads' squared error, from those fits), and
        those that pass the acceptance test with the others in place are taken (the rest dropped, the
        others refitted). Returns them and their held-out gain together, or ([], 0).
        """
        alone = {h.candidate.effect: h for h in fitted if h.candidate.servo_law and h.hold_gain > 0
                 and np.isfinite(h.value)}
        if not alone:
            return [], 0.0
        joints = tuple(self.rep.joints)
        terms = [BY_NAME[n] for n in self.s.candidates if BY_NAME[n].servo_law]
        while terms:
            values = self._fit_together(effects, terms, alone)
            bundle = [self._judge(Hypothesis(c, joints, value=v), effects,
                                  [t.make(joints, values[k]) for k, t in enumerate(terms) if t is not c])
                      for c, v in zip(terms, values)]
            bad = [h for h in bundle if not self.passes(h)]
            if not bad:
                break
            worst = min(bad, key=lambda h: h.hold_gain)
            terms = [c for c in terms if c is not worst.candidate]
        else:
            return [], 0.0
        b0, _ = self._sse(base_pred, joints, 'hold')
        b1, _ = self._sse(self.pred.predict(list(effects) + [h.effect for h in bundle], joints), joints, 'hold')
        return bundle, b0 - b1

    def servo_law_needed(self, accepted: list[Hypothesis], given=()) -> list[Hypothesis]:
        """``accepted`` without the servo-law terms the others do without: each of two or more named
        servo-law terms (weakest first) is left out, the rest refitted (:meth:`refine`), and it stays only
        if it removes ``min_gain_ticks2`` of the held-out squared error that they then leave. A bundle is
        judged in the round it is fitted in, and a term can stand there for what a later round or the
        refit finds (a 2 ms goal latency beside 0.063 N m of punch, fitted while a leg's viscous damping
        was still short: with the damping refitted, the punch alone came to 0.047 N m for 0.048 and every
        joint to tick rounding)."""
        joints = tuple(self.rep.joints)

        def held_out(hs) -> tuple[float, int]:
            return self._sse(self.pred.predict(list(given) + [h.effect for h in hs], joints), joints, 'hold')

        with_it, _ = held_out(accepted)
        for h in sorted([h for h in accepted if h.candidate.servo_law], key=lambda h: h.hold_gain):
            if sum(a.candidate.servo_law for a in accepted) < 2:
                break
            rest = [a for a in accepted if a is not h]
            for _ in range(NEEDED_REFITS):       # refitted once, the first takes what the term left to it
                rest = self.refine(rest, given)
            without, _ = held_out(rest)
            if without - with_it < self.s.min_gain_ticks2:
                self.s.log.append(('servo_law_not_needed', h.candidate.effect, h.value, without - with_it))
                accepted, with_it = rest, without
        return accepted

    def _fit_together(self, effects, terms, alone) -> list[float]:
        """Parameters of servo-law ``terms`` fitted at once on every analysed joint (see above)."""
        from scipy.optimize import minimize
        joints = tuple(self.rep.joints)
        # each parameter scaled by its typical size; nominal values (no term) at 0 except a ratio's 1
        x0 = [(alone[c.effect].value if c.effect in alone else (1.0 if c.two_sided else 0.0)) for c in terms]
        lo = [c.lo if c.two_sided else 0.0 for c in terms]
        hi = [c.hi for c in terms]
        scale = [abs(c.typical - (1.0 if c.two_sided else 0.0)) for c in terms]
        cache: dict[tuple, float] = {}

        def loss(z):
            v = tuple(float(min(max(x0[k] + z[k] * scale[k], lo[k]), hi[k])) for k in range(len(terms)))
            if v not in cache:
                inner = [c.make(joints, x) for c, x in zip(terms, v)
                         if x != (1.0 if c.two_sided else 0.0)]
                cache[v] = self._sse(self.pred.predict(list(effects) + inner, joints), joints, 'fit')[0]
            return cache[v]

        res = minimize(loss, np.zeros(len(terms)), method='Nelder-Mead',
                       options={'initial_simplex': np.vstack([np.zeros(len(terms)), 0.5 * np.eye(len(terms))]),
                                'xatol': 0.02, 'fatol': 1.0, 'maxfev': 60 * len(terms)})
        return [float(min(max(x0[k] + res.x[k] * scale[k], lo[k]), hi[k])) for k in range(len(terms))]

    def _judge(self, h: Hypothesis, effects, others) -> Hypothesis:
        """Fill in ``h``'s fitting and held-out errors at its value, with ``effects`` and ``others`` in place."""
        inner = list(effects) + list(others)
        aff = sorted(affected_joints(h.candidate.effect, h.joints) & set(self.rep.joints))
        base = self.pred.predict(inner, aff)
        self._score_before(h, base)
        if not h.value > h.candidate.lo and not h.candidate.two_sided:
            h.value = math.nan                       # the term is not there at all
            return h
        p = self._score_held_out(h, inner, base, aff)
        h.fit_sse_after, _ = self._sse(p, aff, 'fit')
        return h
