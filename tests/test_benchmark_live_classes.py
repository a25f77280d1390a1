"""benchmarks/live_classes.py: live classes per vehicle from a frames-file; the catalogue motorcycles kept."""

import json


def test_live_classes_count_each_vehicles_frames_by_class(load_benchmark, tmp_path):
    b = load_benchmark("live_classes")
    frames = [{"objects": [{"id": 1, "speed": {"speed_kmh": 50.0, "label": "motorcycle"}}, {"id": 2}]},
              {"objects": [{"id": 1, "speed": {"speed_kmh": 51.0, "label": "car"}},
                           {"id": 2, "speed": {"speed_kmh": 60.0, "label": "truck"}}]},
              {"objects": [{"id": 1, "speed": {"speed_kmh": 51.0, "label": "car"}}]}]
    (tmp_path / "frames.jsonl").write_text("".join(json.dumps(f) + "\n" for f in frames))
    got = b.live_classes(tmp_path / "frames.jsonl")
    assert got == {1: {"motorcycle": 1, "car": 2}, 2: {"truck": 1}}


def test_most_catalogue_motorcycles_keep_their_class(load_benchmark):
    share = load_benchmark("live_classes").kept_share(2000)
    assert 0.98 <= share <= 1.0
