"""One check of a piezo number, shared by the stages that take one."""

import pytest

from gprm.errors import GprmInputError
from gprm.model.linear import generated
from gprm.model.piezo import PIEZOS, check_piezo


@pytest.mark.parametrize("piezo", PIEZOS)
def test_accepts_the_two_piezos(piezo):
    check_piezo(piezo)
    assert generated(piezo).__name__.endswith(f"piezo{piezo}")


@pytest.mark.parametrize("piezo", [0, 3, -1, True, "2", 1.5, None])
def test_refuses_others_with_one_message(piezo):
    with pytest.raises(GprmInputError, match="must be 1 or 2") as e:
        check_piezo(piezo, field="--piezo", source="f.json")
    assert e.value.field == "--piezo" and e.value.source == "f.json"
    with pytest.raises(GprmInputError, match="must be 1 or 2"):
        generated(piezo)


def test_none_is_the_models_own_where_optional():
    check_piezo(None, optional=True)
    with pytest.raises(GprmInputError):
        check_piezo(3, optional=True)


def test_the_stages_use_it():
    from gprm.flight.api import ImpactOptions
    from gprm.predict.scenarios import Scenario, check_scenario
    from gprm.simulate.kinematics import body_motion
    from gprm.params import paper

    for call in (lambda: ImpactOptions(piezo=3), lambda: check_scenario(Scenario("s", 3)),
                 lambda: body_motion(paper(), [0.0, 1e-3], piezo=3)):
        with pytest.raises(GprmInputError, match="must be 1 or 2, got 3"):
            call()
