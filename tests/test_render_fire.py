"""nanovdb-render on files with emission grids (python/nanovdb_mitsuba/fire.py):
which grid glows and how, what it prints, --no-emission, a missing or an
empty emission grid. Tiny renders (24^2, 4 spp): the whole file runs in
well under a minute on two cores."""
import os
import subprocess
import sys

import numpy as np
import pytest

from conftest import MAKE_GRID, ROOT, need_shared_data

sys.path.insert(0, str(ROOT / "python"))
from nanovdb_mitsuba import fire  # noqa: E402
from nanovdb_mitsuba.render import render_file  # noqa: E402

HEAT = "usd_density_heat_fog.vdb"  # density + heat (OpenUSD test data)


def render(path, tmp_path, spp=4, **kw):
    return render_file(str(path), str(tmp_path / "fire.png"), res=24, spp=spp, **kw)


@pytest.fixture(scope="module")
def ball_and_empty(tmp_path_factory):
    """A .nvdb of two grids, "fog_sphere" (a fog ball, 1 inside) and "empty"
    (no active voxels): two NanoVDB files back to back are one file of two
    segments"""
    d = tmp_path_factory.mktemp("fire")
    parts = []
    for name in ("fog_sphere", "empty"):
        subprocess.run([str(MAKE_GRID), name, str(d / f"{name}.nvdb")], check=True,
                       capture_output=True)
        parts.append((d / f"{name}.nvdb").read_bytes())
    out = d / "ball_and_empty.nvdb"
    out.write_bytes(b"".join(parts))
    return out


def test01_grids_are_chosen_by_name_in_order():
    rows = [("density", "float"), ("temperature", "float"), ("Flame", "float"),
            ("vel", "vec3s")]
    assert fire.default_density(rows) == "density"
    # flame (the visible fire) before temperature (the wider heat field)
    assert fire.emission_candidates([n for n, _ in rows], exclude="density") == \
        ["Flame", "temperature"]
    assert fire.choose("f.vdb", rows, "density") == ("Flame", "radiance")
    assert fire.choose("f.vdb", rows, "density", "TEMPERATURE") == ("temperature", "temperature")
    assert fire.choose("f.vdb", rows, "density", "temperature", "radiance") == \
        ("temperature", "radiance")
    assert fire.choose("f.vdb", rows, "density", "none") == (None, "--emission-grid none")
    # The density by name, else the first float grid; never an emission too
    assert fire.default_density([("vel", "vec3s"), ("heat", "float"), ("Density", "float")]) \
        == "Density"
    assert fire.default_density([("vel", "vec3s"), ("smoke", "float")]) == "smoke"
    assert fire.choose("f.vdb", [("heat", "float")], "heat")[0] is None


def test02_blackbody_and_fire_colour():
    import mitsuba as mi
    mi.set_variant("llvm_ad_rgb")
    # Mitsuba's absolute Planck radiance: Y(3000 K) = 414.5 (the integral of
    # Planck x CIE y / 106.857, docs/research/issue21_emission.md)
    assert fire.blackbody_xyz(mi, 3000.0)[1] == pytest.approx(414.5, rel=2e-3)
    assert fire.blackbody_xyz(mi, 1500.0)[1] == pytest.approx(0.1062, rel=5e-3)
    # FIRE_RGB: the 1800 K colour over its luminance, blue clamped to 0
    rgb = fire.blackbody_rgb(mi, fire.FIRE_KELVIN)
    y = fire.blackbody_xyz(mi, fire.FIRE_KELVIN)[1]
    want = [max(c / y, 0.0) for c in rgb]
    np.testing.assert_allclose(fire.FIRE_RGB, want, atol=2e-4)
    assert rgb[2] < 0  # (why the clamp)


def test03_heat_glows_by_default(tmp_path, capsys):
    src = need_shared_data(HEAT) / HEAT
    image, info = render(src, tmp_path)
    out = capsys.readouterr().out
    e = info["emission"]
    assert e["grid"] == "heat" and e["mode"] == "temperature"
    # The max maps to HOTTEST_KELVIN, whose luminance times the scale is BRIGHTNESS
    assert e["max"] * e["temperature_scale"] == pytest.approx(fire.HOTTEST_KELVIN, rel=1e-5)
    assert e["temperature_offset"] == 0.0
    import mitsuba as mi
    y = fire.blackbody_xyz(mi, fire.HOTTEST_KELVIN)[1]
    assert y * e["emission_scale"] == pytest.approx(fire.BRIGHTNESS, rel=1e-5)
    assert 'emission grids: "heat"; "heat" glows: temperature mode' in out, out
    assert "lit by next-event estimation with MIS" in out, out
    assert np.all(np.isfinite(image))


def test04_no_emission_is_darker(tmp_path):
    src = need_shared_data(HEAT) / HEAT
    lit, _ = render(src, tmp_path, spp=32, quiet=True)
    dark, info = render(src, tmp_path, spp=32, quiet=True, emission_grid="none")
    assert info["emission"] is None
    # The same smoke (albedo, scale), less the glow: the fire adds light,
    # most of all in red, and takes none away beyond noise. (Not the same
    # random numbers: next-event estimation toward the fire draws its own,
    # so both renders take 32 spp, enough for the fire's light to stand
    # above their independent noise)
    assert lit.mean() > dark.mean()
    gain = (lit - dark)[..., :3]
    assert gain[..., 0].max() > 0.2, gain[..., 0].max()
    # (blue: a 2800 K fire adds little, less than these renders' noise)
    assert gain[..., 0].sum() > max(gain[..., 2].sum(), 0.0)


def test05_a_missing_grid_names_the_file_and_its_grids(tmp_path):
    src = need_shared_data(HEAT) / HEAT
    with pytest.raises(SystemExit) as e:
        render(src, tmp_path, quiet=True, emission_grid="flame")
    msg = str(e.value)
    assert HEAT in msg and '"flame"' in msg and '"density", "heat"' in msg, msg
    # The command: one line on stderr, no traceback
    env = dict(os.environ, PYTHONPATH=str(ROOT / "python"))
    p = subprocess.run([sys.executable, "-m", "nanovdb_mitsuba.render", str(src), "-o",
                        str(tmp_path / "x.png"), "--emission-grid", "flame"], env=env,
                       capture_output=True, text=True)
    assert p.returncode != 0 and "Traceback" not in p.stderr
    assert p.stderr.strip().splitlines()[-1] == "nanovdb-render: " + msg.split(": ", 1)[1]


def test06_an_empty_emission_grid_renders_without_emission(ball_and_empty, tmp_path, capsys):
    image, info = render(ball_and_empty, tmp_path, emission_grid="empty")
    out = capsys.readouterr().out
    assert 'emission grid "empty" is empty' in out and "without emission" in out, out
    assert info["emission"] is None and info["grid"] == "fog_sphere"
    assert np.all(np.isfinite(image)) and image.std() > 1e-3


def test07_a_fog_ball_as_its_own_temperature_glows(ball_and_empty, tmp_path, capsys):
    # A synthetic fireball: the ball's values (1 inside) as kelvin, the
    # max at HOTTEST_KELVIN: its optically thick inside shows Le, BRIGHTNESS
    image, info = render(ball_and_empty, tmp_path, emission_grid="fog_sphere",
                         emission_mode="temperature")
    assert info["emission"]["grid"] == "fog_sphere"
    assert "temperature mode" in capsys.readouterr().out
    centre = image[10:14, 10:14, :3].mean(axis=(0, 1))
    luminance = centre @ [0.2126, 0.7152, 0.0722]
    assert 0.5 * fire.BRIGHTNESS < luminance < 1.1 * fire.BRIGHTNESS, centre
    assert centre[0] > centre[1] > centre[2]  # 3000 K: orange-white
