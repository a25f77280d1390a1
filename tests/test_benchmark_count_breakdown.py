"""benchmarks/count_breakdown.py's frame rate of a scene: the one end_to_end.py scores by (gt_data.pkl), then the
render's scenario.json, then 25 fps said on stderr — frame numbers of the truth rest on it."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from .conftest import BRNO, require_shared


def _scenario(scene: Path, fps: float) -> None:
    (scene / "scenario.json").write_text(json.dumps({"imaging": {"fps": fps}}))


def test_the_ground_truths_frame_rate_comes_before_the_scenarios(load_benchmark, tmp_path, capsys):
    gt = require_shared(BRNO / "session0_center" / "gt_data.pkl")
    shutil.copy(gt, tmp_path / "gt_data.pkl")
    _scenario(tmp_path, 12.5)  # another rate: which of the two was read shows
    assert load_benchmark("count_breakdown").scene_fps(tmp_path) == 25.0  # the recording's own (real BrnoCompSpeed)
    assert capsys.readouterr().err == ""


def test_without_a_ground_truth_the_scenarios_frame_rate(load_benchmark, tmp_path, capsys):
    _scenario(tmp_path, 12.5)
    assert load_benchmark("count_breakdown").scene_fps(tmp_path) == 12.5
    assert capsys.readouterr().err == ""


def test_without_either_25_fps_and_it_says_so(load_benchmark, tmp_path, capsys):
    (tmp_path / "scenario.json").write_text("{not json")
    assert load_benchmark("count_breakdown").scene_fps(tmp_path) == 25.0
    err = capsys.readouterr().err
    assert str(tmp_path) in err and "taking 25 fps" in err
    (tmp_path / "scenario.json").unlink()  # none at all: the same
    assert load_benchmark("count_breakdown").scene_fps(tmp_path) == 25.0
    assert "taking 25 fps" in capsys.readouterr().err
