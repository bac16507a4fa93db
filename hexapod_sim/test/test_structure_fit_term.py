"""The dictionary search's fit of one term (:func:`hexapod_sim.discrepancy.structure.fit_term`) where the
model cannot take the term at any value: the prediction is stood in for by one that refuses every value,
as the swing-down model does for a dictionary term on a leg with gear backlash."""
import math
import warnings
from types import SimpleNamespace

from hexapod_model.dictionary import BY_TERM
from hexapod_model.joints import Joint
from hexapod_sim.discrepancy import structure

TIBIA = Joint(leg=2, role='tibia')


class _Refusing:
    """A predictor that raises for every set of effects, counting the calls."""

    def __init__(self):
        self.calls = 0

    def predict(self, effects, joints):
        self.calls += 1
        raise ValueError('dictionary terms on a leg with gear backlash are not modelled')


def test_a_term_the_model_refuses_at_every_value_is_not_searched():
    term = BY_TERM['cable_spring']
    pred = _Refusing()
    split = SimpleNamespace(fit={TIBIA: None}, hold={TIBIA: None})
    obj = structure._Objective(pred, split, {}, (), term, (TIBIA,), (TIBIA,))
    n_starts = len(structure._starts(term))
    with warnings.catch_warnings():
        warnings.simplefilter('error')              # no RuntimeWarning from a simplex of inf
        x = structure.fit_term(obj, max_evals=120)
    assert obj.sse(x) == math.inf
    assert tuple(x) in structure._starts(term)     # a start, as given
    assert pred.calls == n_starts + 1              # each start scored once, and the call above
