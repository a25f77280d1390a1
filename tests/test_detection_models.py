"""Model provisioning into the per-user cache, through the library and the CLI (local files only)."""

from __future__ import annotations

import hashlib
import subprocess
import sys

import pytest

from gst_trafficcal.cli import main
from gst_trafficcal.detection import models
from gst_trafficcal.detection.factory import create_detector
from gst_trafficcal.errors import InputError

from .conftest import DETECTORS, require_shared


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    return tmp_path / "xdg" / "gst-trafficcal" / "models"


@pytest.fixture
def model_file():
    return require_shared(DETECTORS / "FastestDet.onnx")


def digest(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_install_list_resolve(cache, model_file):
    h = digest(model_file)
    path = models.install(model_file, h.upper())
    assert path == cache / "FastestDet.onnx" and path.read_bytes() == model_file.read_bytes()
    assert models.install(model_file, h) == path  # again: no-op
    entries = models.list_models()
    assert [(e.name, e.sha256, e.size) for e in entries] == [("FastestDet.onnx", h, model_file.stat().st_size)]
    assert models.resolve_model("FastestDet.onnx") == path
    det = create_detector("FastestDet.onnx")  # installed models are usable by name
    assert det.model_format == "fastestdet"


def test_install_rejects_bad_files(cache, model_file, tmp_path):
    with pytest.raises(InputError, match="SHA-256 mismatch"):
        models.install(model_file, "0" * 64)
    with pytest.raises(InputError, match="64 hexadecimal"):
        models.install(model_file, "abc")
    with pytest.raises(InputError, match="not found"):
        models.install(tmp_path / "none.onnx", "0" * 64)
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"not onnx at all")
    with pytest.raises(InputError, match="not a usable ONNX model"):
        models.install(junk, digest(junk))
    for name in ("sub/x.onnx", "../../evil.onnx", ".."):  # a name is a file in the cache, nowhere else
        with pytest.raises(InputError, match=r"--name .*: a file name in the model cache, without folders"):
            models.install(model_file, digest(model_file), name)
    assert models.list_models() == []  # nothing half-installed
    assert not cache.exists() or not any(cache.iterdir())


def test_install_from_file_url(cache, model_file):
    path = models.install(model_file.as_uri(), digest(model_file), name="fd.onnx")
    assert path.name == "fd.onnx" and digest(path) == digest(model_file)


def test_resolve_errors(cache):
    with pytest.raises(InputError, match="model file not found: nothing.onnx"):
        models.resolve_model("nothing.onnx")


def test_cli_install_and_list(cache, model_file, capsys):
    main(["models", "list"])
    assert "no models installed" in capsys.readouterr().out
    main(["models", "install", str(model_file), "--sha256", digest(model_file)])
    assert str(cache / "FastestDet.onnx") in capsys.readouterr().out
    main(["models", "list"])
    assert "FastestDet.onnx" in capsys.readouterr().out


def test_cli_bad_checksum_is_one_line_error(cache, model_file, tmp_path):
    env = {"XDG_CACHE_HOME": str(tmp_path / "xdg"), "PATH": "/usr/bin:/bin"}
    out = subprocess.run([sys.executable, "-m", "gst_trafficcal", "models", "install", str(model_file),
                          "--sha256", "f" * 64], capture_output=True, text=True, env=env, timeout=60)
    assert out.returncode == 2
    assert out.stderr.startswith("trafficcal: error: ") and "SHA-256 mismatch" in out.stderr
    assert "Traceback" not in out.stderr


def test_factory_tiles_and_background_default():
    from gst_trafficcal.detection.background import BackgroundDetector
    from gst_trafficcal.detection.factory import parse_tiles

    assert parse_tiles("3x2") == (3, 2) and parse_tiles(" 1X1 ") == (1, 1)
    for bad in ("3", "0x2", "ax2", "9x1"):
        with pytest.raises(InputError, match="tiles"):
            parse_tiles(bad)
    assert isinstance(create_detector(""), BackgroundDetector)
