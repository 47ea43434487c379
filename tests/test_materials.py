"""Material presets and Lamé parameters (:mod:`shellsim.physics.materials`)."""

import pytest

from neural.errors import InputError
from shellsim.physics.materials import PRESETS, Material, get_material


def test_lame_parameters_follow_from_youngs_modulus_and_poisson_ratio():
    m = Material("m", 1.0, 0.25, 1.0)
    assert m.mu == pytest.approx(0.4)  # E / (2 (1 + nu))
    assert m.lam == pytest.approx(0.4)  # E nu / ((1 + nu)(1 - 2 nu))
    # back to E and nu: E = mu (3 lam + 2 mu) / (lam + mu), nu = lam / (2 (lam + mu))
    for p in PRESETS.values():
        assert p.mu * (3 * p.lam + 2 * p.mu) / (p.lam + p.mu) == pytest.approx(p.youngs)
        assert p.lam / (2 * (p.lam + p.mu)) == pytest.approx(p.poisson)


def test_presets_have_physical_orders_of_magnitude():
    assert {"rubber", "jelly", "foam", "wood", "metal"} <= set(PRESETS)
    assert (
        PRESETS["jelly"].youngs < PRESETS["foam"].youngs < PRESETS["rubber"].youngs < PRESETS["wood"].youngs
    )
    assert PRESETS["wood"].youngs < PRESETS["metal"].youngs
    assert 7000 < PRESETS["metal"].density < 8100  # steel
    assert PRESETS["foam"].density < 100 < PRESETS["wood"].density < 1000 < PRESETS["rubber"].density


def test_custom_values_override_the_preset():
    m = get_material("Rubber", youngs=5e5, density=900)
    assert (m.name, m.youngs, m.poisson, m.density) == ("rubber", 5e5, PRESETS["rubber"].poisson, 900.0)
    assert get_material("wood") == PRESETS["wood"]


def test_unknown_names_list_the_known_ones():
    with pytest.raises(InputError, match="unknown material 'unobtainium'.*rubber.*metal"):
        get_material("unobtainium")


@pytest.mark.parametrize(
    "kw, what",
    [
        ({"youngs": -1.0}, "Young"),
        ({"poisson": 0.5}, "Poisson"),
        ({"poisson": -1.0}, "Poisson"),
        ({"density": 0.0}, "density"),
        ({"youngs": float("nan")}, "Young"),
        ({"youngs": 1.0}, r"Young's modulus 1 Pa: expected a value in \[100, 2e\+12\] Pa"),
        ({"poisson": 0.5}, r"Poisson ratio 0.5: expected a value in \(-1, 0.5\)"),
        ({"density": 1e6}, r"density 1e\+06 kg/m\^3: expected a value in \[1, 100000\] kg/m\^3"),
    ],
)
def test_out_of_range_values_are_input_errors(kw, what):
    with pytest.raises(InputError, match=what):
        get_material("rubber", **kw)
