"""`trafficcal gst-env` / scripts/env.sh: the environment under which gst-launch-1.0 runs our Python elements.

The gst-python plugin loader embeds Debian's /usr/bin/python3, which has neither numpy nor cv2:
the elements only load when the embedded interpreter sees the venv (venv bin first on PATH, or
the venv's site-packages on PYTHONPATH). Every subprocess uses a private GST_REGISTRY so a stale
registry cache cannot hide a change.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from gst_trafficcal.gst.env import VARIABLES, gst_environment, shell_exports

ROOT = Path(__file__).resolve().parents[1]
PLUGINS = ROOT / "tests" / "gst_plugins"
TRAFFICCAL = [sys.executable, "-m", "gst_trafficcal"]
BASE_PATH = "/usr/local/bin:/usr/bin:/bin"

needs_gst = pytest.mark.skipif(shutil.which("gst-inspect-1.0") is None, reason="GStreamer tools not installed")


def _bash(script: str, env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", "-c", script], env=env, capture_output=True, text=True, timeout=120, cwd=ROOT)


def _clean_env(tmp_path: Path, **extra: str) -> dict[str, str]:
    env = {"HOME": os.environ.get("HOME", str(tmp_path)), "PATH": BASE_PATH,
           "GST_REGISTRY": str(tmp_path / "registry.bin"), **extra}
    return env


def test_cli_prints_the_same_exports_as_env_sh(tmp_path: Path) -> None:
    env = _clean_env(tmp_path)
    show = "; ".join(f'printf "%s=%s\\n" {v} "${v}"' for v in VARIABLES)
    cli = _bash(f'eval "$({" ".join(TRAFFICCAL)} gst-env)"; {show}', env)
    script = _bash(f". scripts/env.sh; {show}", env)
    assert cli.returncode == 0 and script.returncode == 0, cli.stderr + script.stderr
    assert cli.stdout == script.stdout
    values = dict(line.split("=", 1) for line in cli.stdout.splitlines())
    assert values["GST_PLUGIN_PATH"] == str(ROOT / "elements")
    assert values["PATH"].startswith(str(Path(values["VIRTUAL_ENV"]) / "bin") + ":")
    assert values["PYTHONPATH"].split(":")[0] == str(ROOT)
    assert "site-packages" in values["PYTHONPATH"]


def test_exports_are_idempotent_and_quoted() -> None:
    once = gst_environment({"PATH": "/usr/bin", "GST_PLUGIN_PATH": "/opt/my plugins"})
    twice = gst_environment({**once})
    assert once == twice  # eval twice does not grow the variables
    assert once["GST_PLUGIN_PATH"].endswith(":/opt/my plugins")
    assert "export GST_PLUGIN_PATH='" in shell_exports(once)


def test_plugin_dir_option_puts_extra_dirs_after_ours(tmp_path: Path) -> None:
    out = subprocess.run(TRAFFICCAL + ["gst-env", "--plugin-dir", str(PLUGINS)], capture_output=True, text=True,
                         env=_clean_env(tmp_path, PYTHONPATH=str(ROOT)), timeout=60)
    assert out.returncode == 0, out.stderr
    assert f"export GST_PLUGIN_PATH={ROOT / 'elements'}:{PLUGINS}\n" in out.stdout
    bad = subprocess.run(TRAFFICCAL + ["gst-env", "--plugin-dir", str(tmp_path / "missing")], capture_output=True,
                         text=True, env=_clean_env(tmp_path, PYTHONPATH=str(ROOT)), timeout=60)
    assert bad.returncode == 2 and "does not exist" in bad.stderr and "Traceback" not in bad.stderr


@needs_gst
def test_gst_inspect_finds_a_test_element_after_eval(tmp_path: Path) -> None:
    out = _bash(f'eval "$({" ".join(TRAFFICCAL)} gst-env --plugin-dir {PLUGINS})" && gst-inspect-1.0 tcmarker',
                _clean_env(tmp_path))
    assert out.returncode == 0, out.stderr
    assert "tcmarker" in out.stdout and "calibration-file" in out.stdout


@needs_gst
def test_an_element_of_another_make_that_imports_opencv_leaves_ours_loadable(tmp_path: Path) -> None:
    """A plugin folder (--plugin-dir) whose Python element imports cv2: loaded before ours, its OpenCV bootstrap
    left the loader unable to import any of our six elements ("No module named 'vehicledetect'")."""
    (tmp_path / "theirs" / "python").mkdir(parents=True)
    (tmp_path / "theirs" / "python" / "aaacv.py").write_text(
        "import gi\ngi.require_version('Gst', '1.0')\ngi.require_version('GstBase', '1.0')\n"
        "from gi.repository import GObject, Gst, GstBase\nimport cv2  # noqa: F401\n\n\n"
        "class AaaCv(GstBase.BaseTransform):\n    __gstmetadata__ = ('aaacv', 'Filter', 'imports OpenCV', 'test')\n"
        "    __gsttemplates__ = (Gst.PadTemplate.new('src', Gst.PadDirection.SRC, Gst.PadPresence.ALWAYS, "
        "Gst.Caps.new_any()),\n                        Gst.PadTemplate.new('sink', Gst.PadDirection.SINK, "
        "Gst.PadPresence.ALWAYS, Gst.Caps.new_any()))\n\n\n"
        "GObject.type_register(AaaCv)\n__gstelementfactory__ = ('aaacv', Gst.Rank.NONE, AaaCv)\n")
    out = _bash(f'eval "$({" ".join(TRAFFICCAL)} gst-env --plugin-dir {tmp_path / "theirs"})" && '
                "gst-inspect-1.0 aaacv && gst-inspect-1.0 vpdetect && gst-inspect-1.0 speedometer",
                _clean_env(tmp_path))
    assert out.returncode == 0, out.stdout[-1500:] + out.stderr[-1500:]
    assert "imports OpenCV" in out.stdout and "calibration-file" in out.stdout and "events-file" in out.stdout


@needs_gst
@pytest.mark.parametrize("mechanism", ["PATH", "PYTHONPATH"])
def test_either_mechanism_lets_the_embedded_python_see_the_venv(tmp_path: Path, mechanism: str) -> None:
    full = gst_environment({"PATH": BASE_PATH}, plugin_dirs=[PLUGINS])
    env = _clean_env(tmp_path, GST_PLUGIN_PATH=full["GST_PLUGIN_PATH"])
    if mechanism == "PATH":  # venv python3 first on PATH: the embedded interpreter adopts its pyvenv.cfg
        env["PATH"] = full["PATH"]  # (and the editable install's .pth makes gst_trafficcal importable)
    else:
        env["PYTHONPATH"] = full["PYTHONPATH"]
    out = subprocess.run(["gst-inspect-1.0", "tcmarker"], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr


@needs_gst
def test_without_the_venv_the_elements_do_not_load(tmp_path: Path) -> None:
    """The failure the exports prevent: Debian's python3 alone has no numpy/cv2, so the element is missing."""
    env = _clean_env(tmp_path, GST_PLUGIN_PATH=str(PLUGINS), PYTHONPATH=str(ROOT))
    out = subprocess.run(["gst-inspect-1.0", "tcmarker"], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode != 0 and "No such element" in out.stdout + out.stderr
    assert "ModuleNotFoundError: No module named 'numpy'" in out.stderr  # the loader prints the import error


def test_missing_element_directory_is_a_clear_error(tmp_path: Path) -> None:
    from gst_trafficcal.errors import InputError
    from gst_trafficcal.gst.env import elements_dir

    with pytest.raises(InputError, match="element directory not found"):
        elements_dir(tmp_path)
    assert elements_dir(ROOT) == ROOT / "elements"
