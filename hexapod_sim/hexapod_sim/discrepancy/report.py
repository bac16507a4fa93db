"""Step 4 output: the stable JSON document, the plain-language report and the overlay YAML."""
from __future__ import annotations

import math

import yaml

from hexapod_model.description import effects_to_overlay
from hexapod_model.dictionary import BY_TERM
from hexapod_model.joints import joint_names
from hexapod_sim.discrepancy.analysis import Analysis
from hexapod_sim.discrepancy.effects import BY_NAME, scope_name
from hexapod_sim.discrepancy.findings import UNEXPLAINED_TICKS as CLOSE_FIT_TICKS
from hexapod_sim.discrepancy.glitches import summary_line
from hexapod_sim.discrepancy.locate import CONDITION_WORDS, REVEALED_BY, WINDOW_S
from hexapod_sim.discrepancy.predict import least_confirmable_change
from hexapod_sim.discrepancy.segments import PHASES
from hexapod_sim.discrepancy.whole_walk_search import LIFT_OFF_S, ROUNDING_TICKS, TOUCHDOWN_S, WHOLE_PHASES


def _f(x: float) -> float:
    return float(round(x, 4)) if math.isfinite(x) else float('nan')


def to_json(a: Analysis, bag: str | None = None) -> dict:
    """The tool's JSON document (the format is stable; other tools and tests read it)."""
    return {
        'bag': str(bag if bag is not None else a.source),
        'joints': {str(j): {'heldout_rmse_ticks_before': _f(v.heldout_rmse_ticks_before),
                       'heldout_rmse_ticks_after': _f(v.heldout_rmse_ticks_after)}
                   for j, v in a.joints.items() if v.n_heldout > 0},
        'mismatches': [{'joint': str(m.joint), 't_start': _f(m.t_start), 't_end': _f(m.t_end), 'condition': m.condition,
                        'rmse_ticks': _f(m.rmse_ticks), 'peak_rmse_ticks': _f(m.peak_rmse_ticks),
                        **({'phase': m.phase} if m.phase else {})}
                       for m in a.mismatches],
        'phases': {str(j): {ph: {'reads': v.n_reads, 'rmse_ticks_before': _f(v.rmse_ticks_before),
                            'rmse_ticks_after': _f(v.rmse_ticks_after)} for ph, v in row.items()}
                   for j, row in a.phase_fit.items()},
        'effects': [{'effect': f.effect.effect, 'joints': joint_names(f.effect.joints),
                     'params': {k: float(v) for k, v in f.effect.params.items()},
                     'heldout_rmse_ticks_before': _f(f.heldout_rmse_ticks_before),
                     'heldout_rmse_ticks_after': _f(f.heldout_rmse_ticks_after),
                     'servo_law': BY_NAME[f.effect.effect].servo_law} for f in a.effects],
        'cannot_show': {name: joint_names(js) for name, js in a.blind.items()},
        'unexplained': [{'joints': joint_names(u.joints), 'condition': u.condition,
                         'heldout_rmse_ticks': _f(u.heldout_rmse_ticks),
                         **({'nearest': {'effect': u.nearest.effect,
                                         'params': {k: float(v) for k, v in u.nearest.params.items()},
                                         'heldout_rmse_ticks_after': _f(u.nearest_rmse_ticks)}}
                            if u.nearest is not None else {})} for u in a.unexplained],
        'glitches': [{'topic': g.topic, 'joint': g.joint_name, 't': _f(g.t_s), 'kind': g.kind, 'detail': g.detail}
                     for g in a.glitches],
        **({'whole_walk': _whole_walk_json(a.whole_walk)} if a.whole_walk is not None else {}),
        'physics_terms': terms_json(a),
    }


def _whole_walk_json(w) -> dict:
    g = w.ground
    return {'ground': {'terrain': g.terrain, 'seed': int(g.seed), 'start_xy_m': [float(v) for v in g.start_xy_m]},
            'in_step_until_s': _f(w.in_step_until_s), 'nominal_in_step_until_s': _f(w.nominal_in_step_until_s),
            'runtime_s': _f(w.runtime_s),
            'phases': {str(j): {ph: {'reads': v.n_reads, 'rmse_ticks_nominal': _f(v.rmse_ticks_nominal),
                                'rmse_ticks_fitted': _f(v.rmse_ticks_fitted)} for ph, v in row.items()}
                       for j, row in w.phases.items()}}


def _whole_walk_lines(w) -> list[str]:
    used = [ph for ph in WHOLE_PHASES if any(ph in row for row in w.phases.values())]
    lines = ['', f'whole walk on the MuJoCo hexapod ({w.ground.describe()}): RMS error per joint and phase [ticks], '
                 f'nominal -> with the effects (reads to {w.in_step_until_s:.1f} s; touchdown: the first '
                 f'{TOUCHDOWN_S:g} s of stance, lift-off: the first {LIFT_OFF_S:g} s of swing-up):',
             '  ' + f'{"":11s}' + ''.join(f'{ph.replace("_", "-"):>15s}' for ph in used)]
    for j, row in w.phases.items():
        cells = [(f'{row[ph].rmse_ticks_nominal:.2f}->{row[ph].rmse_ticks_fitted:.2f}' if ph in row else '-')
                 for ph in used]
        lines.append('  ' + f'{j:11s}' + ''.join(f'{c:>15s}' for c in cells))
    return lines


def terms_json(a: Analysis) -> list:
    """Dictionary terms named outside the candidate list (:mod:`.structure`), with values, units and wording."""
    return [{'term': t.effect.effect, 'joints': joint_names(t.effect.joints),
             'params': {k: float(v) for k, v in t.effect.params.items()},
             'units': {p.key: p.unit for p in BY_TERM[t.effect.effect].params}, 'description': t.words,
             'heldout_rmse_ticks_before': _f(t.heldout_rmse_ticks_before),
             'heldout_rmse_ticks_after': _f(t.heldout_rmse_ticks_after), 'explained': _f(t.explained)}
            for t in a.terms]


def term_lines(a: Analysis) -> list[str]:
    """Report lines of the dictionary terms named outside the candidate list."""
    return [f'{t.scope}: outside the candidate list, the simulation left out {t.words}; held-out RMS error '
            f'{t.heldout_rmse_ticks_before:.2f} -> {t.heldout_rmse_ticks_after:.2f} ticks '
            f'({100 * t.explained:.0f} % of the excess over rounding).' for t in a.terms]


def text_report(a: Analysis, max_windows: int = 8) -> str:
    """A short plain-language report for a person."""
    judged = {j: v for j, v in a.joints.items() if v.n_heldout > 0}
    lines = _header_lines(a, max_windows)
    lines += _finding_lines(a, judged)
    lines += _blind_lines(a)
    lines += _heldout_lines(a, judged)
    lines += _phase_fit_lines(a)
    if a.whole_walk is not None:
        lines += _whole_walk_lines(a.whole_walk)
    lines += _mismatch_lines(a, judged, max_windows)
    return '\n'.join(lines)


def _header_lines(a: Analysis, max_windows: int) -> list[str]:
    """The recording, the analysis's notes and the glitches of its input."""
    n_reads = sum(len(r.t_s) for r in a.replay.reads.values())
    lines = [f'discrepancy report for {a.source}',
             f'  {a.duration_s:.1f} s recording, {len(a.replay.joints)} joints, {n_reads} reads; '
             f'analysis took {a.runtime_s:.1f} s']
    lines += [f'  note: {n}' for n in a.notes]
    if a.glitches:
        lines.append(f'  note: {summary_line(a.glitches)}:')
        for g in a.glitches[:max_windows]:
            lines.append(f'    {g.topic} {g.joint_name} at {g.t_s:.3f} s: {g.detail}')
        if len(a.glitches) > max_windows:
            lines.append(f'    ... and {len(a.glitches) - max_windows} more (all in --json)')
    lines.append('')
    return lines


def _whole_walk_at_rounding(a: Analysis) -> bool:
    """The whole-walk replay judged every joint and phase at tick rounding."""
    return a.whole_walk is not None and a.whole_walk.worst()[2] <= ROUNDING_TICKS


def _finding_lines(a: Analysis, judged: dict) -> list[str]:
    """What the analysis found: the effects the simulation left out, the dictionary's terms and the
    mismatches no candidate explains (or that nothing is missing)."""
    lines = []
    if not a.effects and judged:
        worst_j, worst = max(judged.items(), key=lambda kv: kv[1].heldout_rmse_ticks_before)
        rmse = worst.heldout_rmse_ticks_before
        if rmse <= CLOSE_FIT_TICKS:
            lines.append('No missing physics found: the nominal model predicts every held-out read to within tick '
                         f'rounding (worst {worst_j}: {rmse:.2f} ticks RMS; rounding alone gives 0.29).')
        elif not a.unexplained and not a.terms and _whole_walk_at_rounding(a):
            wj, wph, wrms = a.whole_walk.worst()
            lines.append(f'No missing physics found: the MuJoCo hexapod replaying the whole walk follows every joint to '
                         f'tick rounding in every phase (worst {wj} in {wph}: {wrms:.2f} ticks RMS). The free-leg '
                         f'model leaves up to {rmse:.2f} ticks on {worst_j}, which the whole walk does not show: '
                         'there the free leg is the model that falls short, not the robot.')
        else:
            lines.append(f'No candidate effect explains the mismatch: the nominal model leaves up to {rmse:.2f} ticks '
                         f'RMS on held-out reads ({worst_j}; rounding alone gives 0.29). The cause lies outside the '
                         'candidate library (e.g. ground contact or body motion during a walk, or a mechanism the '
                         'library does not model); the mismatch windows below show where.')
    for f in a.effects:
        c = BY_NAME[f.effect.effect]
        value = next(iter(f.effect.params.values()))
        if c.servo_law:
            subject = 'the servo law (the firmware of every servo)'
        else:
            subject = f.scope if f.scope != 'the whole robot' else 'every joint (the whole robot)'
        lines.append(f'{subject}: the simulation left out {c.describe(value)}; it shows '
                     f'{CONDITION_WORDS.get(f.condition, f.condition)}; held-out RMS error '
                     f'{f.heldout_rmse_ticks_before:.2f} -> {f.heldout_rmse_ticks_after:.2f} ticks.')
    lines += term_lines(a)
    for u in a.unexplained:
        subject = scope_name(u.joints, a.replay.joints)
        line = (f'{subject}: no candidate explains a mismatch of {u.heldout_rmse_ticks:.2f} ticks RMS held out '
                f'(rounding alone: 0.29); it shows {CONDITION_WORDS.get(u.condition, u.condition)}')
        if u.nearest is not None:
            c = BY_NAME[u.nearest.effect]
            line += (f'; the nearest candidate, {c.describe(next(iter(u.nearest.params.values())))}, leaves '
                     f'{u.nearest_rmse_ticks:.2f} ticks and is not named: something outside the library')
        lines.append(line + '.')
    return lines


def _blind_lines(a: Analysis) -> list[str]:
    """The effects this recording cannot show."""
    if not a.blind:
        return []
    lines = []
    n_j = len(a.replay.joints)
    lines.append('')
    lines.append(f'what this recording cannot show (a typical size of the effect changes the prediction of the '
                 f'fitting or the held-out reads by less than the {least_confirmable_change(a.min_drop_ticks):.2f} '
                 f'tick RMS that an effect needs to gain {a.min_drop_ticks:g} tick over tick rounding, or on too '
                 f'few held-out reads):')
    for name, js in a.blind.items():
        c = BY_NAME[name]
        n_all = n_j - (sum(1 for j in a.replay.joints if j.role == 'coxa') if name == 'mass_error' else 0)
        where = 'any analysed joint' if len(js) == n_all else ', '.join(joint_names(js))
        lines.append(f'  {c.describe(c.typical)} on {where} (it needs {REVEALED_BY[name]}; '
                     'not found there means not shown, not absent)')
    return lines


def _heldout_lines(a: Analysis, judged: dict) -> list[str]:
    """The held-out RMS error per joint, three joints a line."""
    lines = ['']
    lines.append('held-out RMS error per joint [ticks], nominal model -> with the effects:')
    row = []
    for j, v in judged.items():
        row.append(f'{j} {v.heldout_rmse_ticks_before:.2f}->{v.heldout_rmse_ticks_after:.2f}')
        if len(row) == 3:
            lines.append('  ' + '   '.join(row))
            row = []
    if row:
        lines.append('  ' + '   '.join(row))
    unjudged = [j for j, v in a.joints.items() if v.n_heldout == 0]
    if unjudged:
        lines.append(f'  (no held-out reads, not judged: {", ".join(joint_names(unjudged))})')
    return lines


def _phase_fit_lines(a: Analysis) -> list[str]:
    """A walk's RMS error per joint and gait phase."""
    if not a.phase_fit:
        return []
    lines = ['']
    lines.append('walk: RMS error per joint and gait phase [ticks], nominal -> with the effects (analysed reads; '
                 'stance and leveling are not analysed: the leg carries the body there):')
    used = [ph for ph in PHASES if any(ph in row for row in a.phase_fit.values())]
    lines.append('  ' + f'{"":11s}' + ''.join(f'{ph.replace("_", "-"):>16s}' for ph in used))
    for j, row in a.phase_fit.items():
        cells = [(f'{row[ph].rmse_ticks_before:.2f}->{row[ph].rmse_ticks_after:.2f}' if ph in row else '-')
                 for ph in used]
        lines.append('  ' + f'{j:11s}' + ''.join(f'{c:>16s}' for c in cells))
    return lines


def _mismatch_lines(a: Analysis, judged: dict, max_windows: int) -> list[str]:
    """The largest windows where the nominal replay departs from the recording beyond tick rounding."""
    if not a.mismatches:
        return ['', 'No time window departs from the nominal replay beyond tick rounding.']
    lines = ['']
    close = not a.effects and judged and max(v.heldout_rmse_ticks_before for v in judged.values()) <= CLOSE_FIT_TICKS
    if close:
        lines.append(f'{len(a.mismatches)} short stretch(es) where the residual over {WINDOW_S:g} s briefly exceeds '
                     'tick rounding, too brief to raise the held-out RMS above it; largest '
                     f'{min(max_windows, len(a.mismatches))}:')
    else:
        lines.append(f'{len(a.mismatches)} mismatch window(s) where the residual over {WINDOW_S:g} s exceeds tick '
                     f'rounding in the nominal replay; largest {min(max_windows, len(a.mismatches))}:')
    lines.append(f'  {"joint":11s} {"window [s]":>15s}  {"peak":>5s} / {"whole":>5s} ticks RMS  condition')
    for m in sorted(a.mismatches, key=lambda m: -m.rmse_ticks * math.sqrt(m.t_end - m.t_start + 1e-3))[:max_windows]:
        lines.append(f'  {m.joint:11s} {m.t_start:7.2f}-{m.t_end:7.2f}  {m.peak_rmse_ticks:5.2f} / {m.rmse_ticks:5.2f}'
                     f'             {m.condition}' + (f' ({m.phase.replace("_", "-")})' if m.phase else ''))
    return lines


def overlay_yaml(a: Analysis) -> str:
    """The fitted effects as a robot-description overlay (``load_robot(overlays=[...])``)."""
    head = (f'# Robot-description overlay written by the discrepancy tool from {a.source}.\n'
            '# Load with hexapod_model.description.load_robot(overlays=[this file]); the swing-down model and\n'
            '# the MuJoCo sim both apply these effects.\n')
    return head + yaml.safe_dump(effects_to_overlay(a.found), sort_keys=False)
