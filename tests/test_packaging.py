"""The built wheel is self-contained: it carries the GStreamer element files and the vehicle catalogue (kept in the
repository as elements/ and models3d/, mapped into the package by setup.py), and an installed copy runs from a
directory outside the checkout: `trafficcal gst-env`, gst-inspect-1.0, a pipeline of our elements, a synth render.

The wheel is built offline (no build isolation, no index) from a copy of the checkout, so that the build's
scratch directories (build/, *.egg-info) never land in the checkout.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BASE_PATH = "/usr/local/bin:/usr/bin:/bin"
ELEMENTS = ("bbscale", "speedometer", "tracker", "trafficoverlay", "vehicledetect", "vpdetect")

pytestmark = [pytest.mark.gst, pytest.mark.skipif(shutil.which("gst-launch-1.0") is None,
                                                  reason="GStreamer tools not installed")]


def _run(cmd: list[str], **kw) -> subprocess.CompletedProcess:
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=120, **kw)
    assert out.returncode == 0, f"{cmd}: {out.stdout[-2000:]}{out.stderr[-3000:]}"
    return out


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The wheel built from a copy of this checkout with the venv's pip, offline."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    shutil.copytree(ROOT, src, symlinks=True, ignore=shutil.ignore_patterns(
        ".venv", ".git", "build", "*.egg-info", "__pycache__", ".pytest_cache", ".hypothesis", "out"))
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index",
          "--disable-pip-version-check", "-q", "-w", str(tmp / "dist"), str(src)])
    (whl,) = (tmp / "dist").glob("gst_trafficcal-*.whl")
    return whl


def test_the_wheel_carries_the_elements_catalogue_presets_and_weights_and_no_tests(wheel: Path) -> None:
    names = set(zipfile.ZipFile(wheel).namelist())
    for name in ELEMENTS:
        assert f"gst_trafficcal/elements/python/{name}.py" in names
    assert "gst_trafficcal/models3d/catalogue.yaml" in names
    assert "gst_trafficcal/synth/presets/highway_day.yaml" in names
    assert "gst_trafficcal/detection/weights/vehicleseg.onnx" in names
    assert "gst_trafficcal/detection/weights/vehicleseg.json" in names
    # nothing but the package and its metadata: no tests, benchmarks, training, pipelines
    assert {n.split("/")[0] for n in names} == {"gst_trafficcal", wheel.name.split("-py3")[0] + ".dist-info"}
    assert not [n for n in names if "/tests/" in n or "benchmarks" in n or n.endswith("__init__.py")
                and "/elements/" in n]


def test_the_installed_wheel_runs_outside_the_checkout(wheel: Path, tmp_path: Path) -> None:
    target, work = tmp_path / "site", tmp_path / "work"
    work.mkdir()
    _run([sys.executable, "-m", "pip", "install", "--no-deps", "--no-index", "--disable-pip-version-check", "-q",
          "--target", str(target), str(wheel)])
    env = {"HOME": os.environ.get("HOME", str(tmp_path)), "PATH": BASE_PATH, "PYTHONPATH": str(target),
           "GST_REGISTRY": str(tmp_path / "registry.bin")}
    where = _run([sys.executable, "-c", "import gst_trafficcal.vehicles.catalogue as c, gst_trafficcal.gst.env as e;"
                 "print(c.__file__); print(c.DEFAULT_CATALOGUE); print(e.elements_dir())"], env=env, cwd=work)
    # the installed copy wins over the checkout's editable install
    assert where.stdout.split() == [str(target / "gst_trafficcal/vehicles/catalogue.py"),
                                    str(target / "gst_trafficcal/models3d/catalogue.yaml"),
                                    str(target / "gst_trafficcal/elements")]

    trafficcal = f"{sys.executable} -m gst_trafficcal"
    show = 'printf "%s\\n" "$GST_PLUGIN_PATH" "$PYTHONPATH"'
    exports = _run(["bash", "-c", f'eval "$({trafficcal} gst-env)" && {show} && gst-inspect-1.0 vpdetect'],
                   env=env, cwd=work)
    plugin_path, python_path = exports.stdout.splitlines()[:2]
    assert plugin_path == str(target / "gst_trafficcal/elements")
    assert python_path.split(":")[0] == str(target)
    assert "vpdetect" in exports.stdout and "Factory Details" in exports.stdout

    # without GStreamer's Python plugin loader (here: a system plugin directory without it) gst-inspect-1.0 finds
    # none of our elements, and gst-env says why, exporting nothing
    no_loader = dict(env, GST_PLUGIN_SYSTEM_PATH_1_0=str(tmp_path / "no-plugins"))
    missing = subprocess.run(["gst-inspect-1.0", "vpdetect"],
                             env=dict(no_loader, GST_PLUGIN_PATH=plugin_path, PYTHONPATH=python_path),
                             capture_output=True, text=True, timeout=120, cwd=work)
    assert missing.returncode != 0 and "No such element" in missing.stdout + missing.stderr
    refused = subprocess.run(["bash", "-c", f"{trafficcal} gst-env"], env=no_loader, capture_output=True, text=True,
                             timeout=120, cwd=work)
    assert refused.returncode != 0 and refused.stdout == ""
    assert "libgstpython.so" in refused.stderr and "gstreamer1.0-python3-plugin-loader" in refused.stderr

    # a render from the catalogue's vehicles, then our elements on it, all from the installed copy
    _run(["bash", "-c", f"{trafficcal} synth --preset highway_day --duration 2 --seed 1 --out clip --no-progress"],
         env=env, cwd=work)
    pipeline = ("filesrc location=clip/video.mp4 ! decodebin ! videoconvert ! vpdetect ! tracker ! fakesink")
    ran = _run(["bash", "-c", f'eval "$({trafficcal} gst-env)" && gst-launch-1.0 -q {pipeline}'], env=env, cwd=work)
    assert "ERROR" not in ran.stdout + ran.stderr
