"""``ftafm.fm``: the Sader–Jarvis inversion gives ``ftafm fm-invert``'s numbers on the same
curve; forward model then inversion returns the force law; the forward model has the
small-amplitude and closed-form limits; bad input is refused naming the parameter or
the sample, in the Rust command's words."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

import ftafm
from ftafm import fm

# A DMT-like law with a silicon-ish tip: van der Waals −HR/(6d²) outside a0; Hertz plus
# the pull-off at a0 inside (N of m, repulsive positive).
E_STAR, RADIUS, HAMAKER, A0 = 1e9, 10e-9, 1e-19, 0.3e-9


def dmt(d: np.ndarray) -> np.ndarray:
    vdw = -HAMAKER * RADIUS / (6.0 * np.maximum(d, A0) ** 2)
    hertz = 4.0 / 3.0 * E_STAR * np.sqrt(RADIUS) * np.maximum(A0 - d, 0.0) ** 1.5
    return vdw + hertz


def van_der_waals(d: np.ndarray) -> np.ndarray:
    return -HAMAKER * RADIUS / (6.0 * d**2)


#: The contact point of the Hertz law (m): no force above it.
OFFSET = 0.2e-9


def hertz_with_offset(d: np.ndarray) -> np.ndarray:
    return 4.0 / 3.0 * E_STAR * np.sqrt(RADIUS) * np.maximum(OFFSET - d, 0.0) ** 1.5


def exponential(d: np.ndarray) -> np.ndarray:
    return -1e-9 * np.exp(-d / 0.5e-9)


# ---- (1) the same numbers as `ftafm fm-invert` -------------------------------------------


@pytest.fixture(scope="module")
def binary() -> str:
    exe = os.environ.get("FTAFM_BIN") or shutil.which("ftafm")
    if not exe:
        pytest.fail("no ftafm binary: set FTAFM_BIN or put ftafm on the PATH")
    return exe


def write_curve(path: Path, z: np.ndarray, df: np.ndarray) -> None:
    """The CSV `ftafm fm-invert` reads; repr() writes each float so it reads back exact."""
    lines = ["# Δf(z) from ftafm.fm.frequency_shift", "z,df"]
    lines += [f"{float(a)!r},{float(b)!r}" for a, b in zip(z, df)]
    path.write_text("\n".join(lines) + "\n")


def fm_invert(binary: str, path: Path, *flags: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [binary, "fm-invert", str(path), *flags], capture_output=True, text=True, timeout=60
    )


LEVER = {"k": 20.0, "f0": 1e5, "amplitude": 5e-9}


def lever_flags(k: float, f0: float, amplitude: float) -> list[str]:
    return [f"--k={k!r}", f"--f0={f0!r}", f"--amplitude={amplitude!r}"]


@pytest.mark.parametrize(
    ("amplitude", "z"),
    [
        (5e-9, np.linspace(A0 - 0.5e-9, 30e-9, 400)),
        (0.2e-9, np.linspace(A0 - 0.5e-9, 30e-9, 300)),
        # Uneven: 2 pm steps near the surface growing 1 % a step (600 samples: the Python
        # side sums in two blocks of rows).
        (1e-9, A0 - 0.5e-9 + np.cumsum(2e-12 * 1.01 ** np.arange(600))),
    ],
    ids=["A=5nm", "A=0.2nm", "A=1nm-uneven"],
)
def test_the_inversion_is_the_rust_commands(
    binary: str, tmp_path: Path, amplitude: float, z: np.ndarray
) -> None:
    lever = dict(LEVER, amplitude=amplitude)
    df = fm.frequency_shift(dmt, z, **lever)
    path = tmp_path / "curve.csv"
    write_curve(path, z, df)

    out = fm_invert(binary, path, *lever_flags(**lever), "--json")
    assert out.returncode == 0, out.stderr
    rust = json.loads(out.stdout)
    rust_z, rust_force = np.array(rust["z"]), np.array(rust["force"])
    curve = fm.invert(z, df, **lever)

    assert len(curve.z) == len(curve.force) == len(z) - 1, "every sample but the last"
    assert np.argmin(curve.force) > 0, "the adhesion well: contact, then attraction"
    np.testing.assert_array_equal(curve.z, rust_z)
    relative = np.max(np.abs(curve.force - rust_force)) / np.max(np.abs(rust_force))
    print(f"A = {amplitude:g} m, {len(z)} samples: max |ΔF|/max|F| = {relative:.3g}")
    # The same operations in the same order: equal to the last bit (measured: 0 at each
    # of these); the bound allows another platform's libm a few ulps.
    assert relative < 1e-12
    scale = np.max(np.abs(rust_force))
    np.testing.assert_allclose(curve.force, rust_force, rtol=1e-12, atol=1e-12 * scale)

    # The CSV output too (Rust's `{:e}` writes shortest round-trip digits).
    out = fm_invert(binary, path, *lever_flags(**lever))
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0] == "z,force"
    table = np.array([[float(v) for v in line.split(",")] for line in lines[1:]])
    np.testing.assert_array_equal(table[:, 0], curve.z)
    np.testing.assert_allclose(table[:, 1], curve.force, rtol=1e-12, atol=1e-12 * scale)


def test_refusals_are_the_rust_commands_words(binary: str, tmp_path: Path) -> None:
    path = tmp_path / "curve.csv"
    write_curve(path, np.array([1e-9, 2e-9, 3e-9]), np.array([-3.0, -2.0, -1.0]))
    out = fm_invert(binary, path, *lever_flags(k=-1.0, f0=1e5, amplitude=1e-9))
    assert out.returncode == 2
    with pytest.raises(fm.ParameterError) as e:
        fm.invert([1e-9, 2e-9, 3e-9], [-3.0, -2.0, -1.0], k=-1.0, f0=1e5, amplitude=1e-9)
    assert f"--k: {e.value}" in out.stderr, (str(e.value), out.stderr)

    write_curve(path, np.array([1e-9, 3e-9, 2e-9]), np.array([-3.0, -2.0, -1.0]))
    out = fm_invert(binary, path, *lever_flags(**LEVER))
    assert out.returncode == 2
    with pytest.raises(fm.NotIncreasingError) as e:
        fm.invert([1e-9, 3e-9, 2e-9], [-3.0, -2.0, -1.0], **LEVER)
    # Numbers as Rust's `{}` writes them, so the two messages are the same text.
    assert str(e.value) == (
        "z must increase strictly: z[2] = 0.000000002 follows z[1] = 0.000000003"
    )
    assert f"{path}:5: {e.value}" in out.stderr, (str(e.value), out.stderr)

    write_curve(path, np.array([1e-9, 3e-9]), np.array([-3.0, -2.0]))
    out = fm_invert(binary, path, *lever_flags(**LEVER))
    assert out.returncode == 2
    with pytest.raises(fm.TooShortError) as e:
        fm.invert([1e-9, 3e-9], [-3.0, -2.0], **LEVER)
    assert f"{path}: {e.value}" in out.stderr, (str(e.value), out.stderr)


# ---- (2) forward model, then inversion: the force law comes back -------------------------

#: The amplitudes the Rust tests (src/physics/fm/sader_jarvis.rs) check at (m).
AMPLITUDES = [1e-13, 0.02e-9, 0.2e-9, 1e-9, 20e-9]


def worst_error(law: Callable[[np.ndarray], np.ndarray], z: np.ndarray, amplitude: float) -> float:
    """The worst |F_recovered − F| over the curve as a fraction of the law's range there."""
    lever = {"k": 30.0, "f0": 300e3, "amplitude": amplitude}
    curve = fm.invert(z, fm.frequency_shift(law, z, **lever), **lever)
    exact = law(curve.z)
    return float(np.max(np.abs(curve.force - exact)) / np.ptp(exact))


# The bounds sit just above what the inversion achieves (measured, in % of the range:
# van der Waals 0.45, 2.4, 1.7, 0.9, 1.3; Hertz 0.21, 1.4, 3.2, 0.34, 0.23), as the Rust
# tests' do. Hertz: the grid is converged (3000 samples move the errors by < 0.03 points), so
# this is the formula's own approximation error, largest where A is comparable to the
# length over which the force changes; the bounds are the Rust test's for a Hertz contact
# (at d = 0 there; the offset changes nothing). Van der Waals: the worst error sits at the
# closest sample, where −HR/(6d²) is steepest, and falls with a finer grid (to 0.3, 2.4,
# 1.2, 0.3, 0.6 % at 3000 samples) but at A = 0.02 nm.
@pytest.mark.parametrize(
    ("name", "law", "z", "bounds"),
    [
        (
            "van der Waals",
            van_der_waals,
            np.linspace(0.3e-9, 30e-9, 1500),
            [0.01, 0.03, 0.025, 0.015, 0.02],
        ),
        (
            "Hertz with offset",
            hertz_with_offset,
            np.linspace(OFFSET - 0.5e-9, OFFSET + 5e-9, 1500),
            [0.005, 0.02, 0.04, 0.01, 0.005],
        ),
    ],
    ids=["vdw", "hertz"],
)
def test_forward_then_inverse_returns_the_law(
    name: str, law: Callable[[np.ndarray], np.ndarray], z: np.ndarray, bounds: list[float]
) -> None:
    for amplitude, bound in zip(AMPLITUDES, bounds):
        e = worst_error(law, z, amplitude)
        print(f"{name}, A = {amplitude:g} m: worst error {100 * e:.3f} % of the range")
        assert e < bound, (amplitude, e)


def test_a_zero_frequency_shift_is_no_force() -> None:
    curve = ftafm.fm.invert(np.linspace(0, 1e-8, 50), np.zeros(50), k=1.0, f0=1e5, amplitude=1e-9)
    assert len(curve.z) == 49 and np.all(curve.force == 0.0)
    z, force = curve  # a tuple
    assert z is curve.z and force is curve.force


# ---- (3) the forward model's limits ------------------------------------------------------


def test_small_amplitudes_give_the_force_gradient() -> None:
    # Δf → −f0/(2k)·dF/dz at the orbit's centre z + A when A ≪ the force's length scale.
    k, f0, a = 2.0, 70e3, 1e-13
    z = np.array([0.2e-9, 1e-9, 2e-9])
    cases = [
        (exponential, lambda d: 1e-9 / 0.5e-9 * np.exp(-d / 0.5e-9)),
        (van_der_waals, lambda d: HAMAKER * RADIUS / (3.0 * d**3)),
    ]
    for law, gradient in cases:
        got = fm.frequency_shift(law, z, k=k, f0=f0, amplitude=a)
        want = -f0 / (2.0 * k) * gradient(z + a)
        assert np.all(got < 0), "attraction lowers the resonance"
        np.testing.assert_allclose(got, want, rtol=1e-6)
        # Few nodes suffice for a tiny orbit (the Rust test uses 64).
        np.testing.assert_allclose(
            fm.frequency_shift(law, z, k=k, f0=f0, amplitude=a, nodes=64), want, rtol=1e-6
        )


def bessel_i1(x: float) -> float:
    """I₁(x) by its power series (x up to ~50)."""
    term = total = x / 2.0
    for m in range(1, 200):
        term *= x * x / 4.0 / (m * (m + 1.0))
        total += term
        if term < 1e-17 * total:
            break
    return total


def test_the_exponential_law_gives_giessibls_closed_form() -> None:
    # F = −F0·exp(−d/λ): Δf = −f0/(k·A)·F0·exp(−(d + A)/λ)·I₁(A/λ) at any amplitude.
    f0_force, decay = 1e-9, 0.2e-9
    d = np.array([0.1e-9, 0.5e-9])
    for a in [1e-12, 0.1e-9, 1e-9, 5e-9]:
        got = fm.frequency_shift(
            lambda x: -f0_force * np.exp(-x / decay), d, k=30.0, f0=300e3, amplitude=a
        )
        want = -300e3 / (30.0 * a) * f0_force * np.exp(-(d + a) / decay) * bessel_i1(a / decay)
        np.testing.assert_allclose(got, want, rtol=1e-9)


def test_the_forward_model_keeps_the_shape_of_z() -> None:
    lever = {"k": 30.0, "f0": 300e3, "amplitude": 1e-9}
    scalar = fm.frequency_shift(exponential, 0.5e-9, **lever)
    assert np.shape(scalar) == ()
    grid = fm.frequency_shift(exponential, np.full((2, 3), 0.5e-9), **lever)
    assert grid.shape == (2, 3) and np.all(grid == scalar)
    # A law that returns a constant (a scalar) is broadcast: no force, no shift.
    assert np.all(fm.frequency_shift(lambda d: 0.0, [1e-9, 2e-9], **lever) == 0.0)
    # More distances than one block of the quadrature's arrays.
    z = np.linspace(0.1e-9, 10e-9, 300)
    pieces = [fm.frequency_shift(exponential, z[i : i + 7], **lever) for i in range(0, 300, 7)]
    whole = fm.frequency_shift(exponential, z, **lever)
    np.testing.assert_array_equal(whole, np.concatenate(pieces))


# ---- (4) bad input, refused by name ------------------------------------------------------


@pytest.mark.parametrize(
    ("k", "f0", "amplitude", "name"),
    [
        (0.0, 1e5, 1e-9, "k"),
        (float("nan"), 1e5, 1e-9, "k"),
        (1.0, -1e5, 1e-9, "f0"),
        (1.0, 1e5, 0.0, "amplitude"),
        (1.0, 1e5, float("inf"), "amplitude"),
    ],
)
def test_bad_lever_parameters_are_refused_by_name(
    k: float, f0: float, amplitude: float, name: str
) -> None:
    for call in (
        lambda: fm.invert([0.0, 1.0, 2.0], [0.0] * 3, k=k, f0=f0, amplitude=amplitude),
        lambda: fm.frequency_shift(exponential, [1e-9], k=k, f0=f0, amplitude=amplitude),
    ):
        with pytest.raises(fm.ParameterError) as e:
            call()
        assert isinstance(e.value, ValueError) and isinstance(e.value, ftafm.FmError)
        assert e.value.name == name
        assert str(e.value).startswith(f"{name} = "), e.value
        assert "is out of range: allowed a finite" in str(e.value)


def test_bad_curves_are_refused_naming_the_input() -> None:
    lever = {"k": 1.0, "f0": 1e5, "amplitude": 1e-9}
    z = [0.0, 1.0, 2.0]
    with pytest.raises(fm.LengthsError, match=r"^z has 3 samples but df has 2: give one") as e:
        fm.invert(z, [0.0, 0.0], **lever)
    assert (e.value.z, e.value.df) == (3, 2)
    with pytest.raises(fm.TooShortError, match=r"^2 samples given: at least 3 are needed$"):
        fm.invert(z[:2], [0.0] * 2, **lever)
    with pytest.raises(fm.NotIncreasingError, match=r"z\[2\] = 1 follows z\[1\] = 2$") as e:
        fm.invert([0.0, 2.0, 1.0], [0.0] * 3, **lever)
    assert (e.value.index, e.value.value, e.value.previous) == (2, 1.0, 2.0)
    with pytest.raises(fm.NotIncreasingError) as e:
        fm.invert([0.0, 1.0, 1.0], [0.0] * 3, **lever)
    assert e.value.index == 2
    with pytest.raises(fm.NotFiniteError, match=r"^df\[1\] = NaN is not finite$") as e:
        fm.invert(z, [0.0, float("nan"), 0.0], **lever)
    assert (e.value.name, e.value.index) == ("df", 1)
    # z is checked before df, and for finiteness before its order.
    with pytest.raises(fm.NotFiniteError, match=r"^z\[1\] = inf is not finite$"):
        fm.invert([0.0, float("inf"), 3.0], [0.0, float("nan"), 0.0], **lever)
    with pytest.raises(fm.FmError, match="one-dimensional"):
        fm.invert(np.zeros((3, 2)), np.zeros((3, 2)), **lever)
    with pytest.raises(fm.NotFiniteError, match=r"^z\[1\] = -inf is not finite$"):
        fm.frequency_shift(exponential, [1e-9, -np.inf], **lever)
    with pytest.raises(fm.ParameterError, match=r"^nodes = 0 is out of range"):
        fm.frequency_shift(exponential, [1e-9], **lever, nodes=0)
