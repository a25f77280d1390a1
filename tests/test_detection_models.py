"""Model provisioning into the per-user cache, through the library and the CLI (local files only)."""

from __future__ import annotations

import hashlib
import os
import re
import subprocess
import sys
from pathlib import Path

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


@pytest.fixture
def other_model():
    return require_shared(DETECTORS / "nanodet_hpc203.onnx")


def digest(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def trafficcal(*args: object, cache_home: Path) -> subprocess.CompletedProcess:
    """``trafficcal ARGS`` in a new process with XDG_CACHE_HOME=cache_home."""
    env = {**os.environ, "XDG_CACHE_HOME": str(cache_home)}
    return subprocess.run([sys.executable, "-m", "gst_trafficcal", *map(str, args)], capture_output=True, text=True,
                          env=env, timeout=60)


def test_install_list_resolve(cache, model_file):
    h = digest(model_file)
    done = models.install(model_file, h.upper())
    path = done.path
    assert done.action == "installed"
    assert path == cache / "FastestDet.onnx" and path.read_bytes() == model_file.read_bytes()
    assert models.install(model_file, h) == models.Installed(path, "unchanged")  # again: no-op
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
    path = models.install(model_file.as_uri(), digest(model_file), name="fd.onnx").path
    assert path.name == "fd.onnx" and digest(path) == digest(model_file)


def test_resolve_errors(cache):
    with pytest.raises(InputError, match="model file not found: nothing.onnx"):
        models.resolve_model("nothing.onnx")


def test_resolve_says_which_place_it_could_not_search(cache, monkeypatch):
    """A cache folder this user may not search (root is never refused, so the refusal is the file system's answer
    given by hand): one line naming the place, not a PermissionError traceback."""
    real = Path.is_file

    def refused(self: Path) -> bool:
        if self.parent == cache:
            raise PermissionError(13, "Permission denied", str(self))
        return real(self)

    monkeypatch.setattr(Path, "is_file", refused)
    with pytest.raises(InputError, match=re.escape(f"{cache / 'fd.onnx'}: cannot look for model fd.onnx there "
                                                   "(Permission denied)")):
        models.resolve_model("fd.onnx")


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


def test_a_cache_that_cannot_be_made_is_one_line_naming_it(tmp_path, model_file):
    """XDG_CACHE_HOME where no folder can be made (under a regular file; in /proc): a one-line error naming the
    cache and the problem, exit 2 — was a FileNotFoundError traceback from mkdir (a PermissionError from mkstemp
    for a cache the user may not write, which takes the same path)."""
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    for home, why in ((blocker / "cache", "Not a directory"), (Path("/proc/no-such-cache"), "No such file")):
        run = trafficcal("models", "install", model_file, "--sha256", digest(model_file), cache_home=home)
        assert run.returncode == 2 and "Traceback" not in run.stderr, run.stderr
        assert run.stderr.startswith(f"trafficcal: error: cannot write to the model cache {home}/gst-trafficcal/"
                                     f"models ({why}") and run.stderr.count("\n") == 1, run.stderr
        listed = trafficcal("models", "list", cache_home=home)
        assert listed.returncode == 0 and listed.stdout.startswith("no models installed"), listed.stderr


def test_installed_models_have_the_usual_permissions(cache, model_file, other_model):
    """0666 less the umask, like any new file (was 0600 from mkstemp: a cache shared with a service account could
    not be read by it)."""
    old = os.umask(0o022)
    try:
        assert models.install(model_file, digest(model_file)).path.stat().st_mode & 0o777 == 0o644
        os.umask(0o027)
        assert models.install(other_model, digest(other_model)).path.stat().st_mode & 0o777 == 0o640
    finally:
        os.umask(old)


def test_an_unreadable_model_is_listed_with_a_note(cache, model_file, tmp_path):
    """`models list` lists a model it cannot read with the reason and goes on (was a traceback from sha256_of); a
    model of that name is not replaced unawares.  /proc/self/mem cannot be read from its start even by root."""
    if not os.path.isfile("/proc/self/mem"):
        pytest.skip("needs /proc/self/mem (Linux)")
    models.install(model_file, digest(model_file))
    (cache / "broken.onnx").symlink_to("/proc/self/mem")
    good, broken = models.list_models()  # sorted by name
    assert (broken.name, broken.sha256) == ("broken.onnx", None) and broken.problem.startswith("cannot read it (")
    assert (good.name, good.sha256, good.problem) == ("FastestDet.onnx", digest(model_file), "")
    run = trafficcal("models", "list", cache_home=tmp_path / "xdg")
    assert run.returncode == 0 and run.stderr == "", run.stderr
    assert run.stdout.splitlines()[0].startswith(f"FastestDet.onnx\t{model_file.stat().st_size}\t{digest(model_file)}")
    assert run.stdout.splitlines()[1].startswith(f"broken.onnx\t0\t-\t{cache / 'broken.onnx'}\tcannot read it (")
    with pytest.raises(InputError, match=r"broken.onnx: cannot read the model installed under this name \(.*\); "
                                         r"pass --force to replace it"):
        models.install(model_file, digest(model_file), name="broken.onnx")
    assert models.install(model_file, digest(model_file), "broken.onnx", force=True).action == "replaced"
    assert not (cache / "broken.onnx").is_symlink() and digest(cache / "broken.onnx") == digest(model_file)


def test_a_different_model_under_an_installed_name_needs_force(cache, model_file, other_model, tmp_path):
    """Installing another file under a name in use is refused (was replaced silently) unless --force; the same file
    again is fine and says so."""
    def install(*extra: object) -> subprocess.CompletedProcess:
        return trafficcal("models", "install", *extra, cache_home=tmp_path / "xdg")

    assert install(model_file, "--sha256", digest(model_file)).returncode == 0
    refused = install(other_model, "--sha256", digest(other_model), "--name", "FastestDet.onnx")
    assert refused.returncode == 2 and refused.stderr == (
        f"trafficcal: error: {cache / 'FastestDet.onnx'}: a different model is installed under this name (SHA-256 "
        f"{digest(model_file)}); pass --force to replace it, or --name to install under another name\n")
    assert digest(cache / "FastestDet.onnx") == digest(model_file)
    again = install(model_file, "--sha256", digest(model_file))
    assert again.returncode == 0 and again.stdout == f"{cache / 'FastestDet.onnx'}\n"
    assert "was installed already (the same file): nothing changed" in again.stderr
    forced = install(other_model, "--sha256", digest(other_model), "--name", "FastestDet.onnx", "--force")
    assert forced.returncode == 0 and "replaced the model installed as FastestDet.onnx" in forced.stderr
    assert digest(cache / "FastestDet.onnx") == digest(other_model)
    assert [e.name for e in models.list_models()] == ["FastestDet.onnx"]  # no temporary file left


def test_install_errors_name_what_the_user_gave(cache, tmp_path):
    """A folder as SOURCE is said to be one (was "model file not found"); a file onnxruntime cannot load is named
    as given (was the cache's temporary .part- file)."""
    folder = tmp_path / "models"
    folder.mkdir()
    with pytest.raises(InputError, match=f"^{folder}: a directory, not a model file$"):
        models.install(folder, "0" * 64)
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"not onnx at all")
    with pytest.raises(InputError) as err:
        models.install(junk, digest(junk))
    assert str(err.value).startswith(f"{junk}: not a usable ONNX model (") and ".part-" not in str(err.value)
    assert str(junk) in str(err.value).split("(", 1)[1]  # onnxruntime's own words name it too
