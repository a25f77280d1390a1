"""Speed errors of the speedometer element on the rendered test clip of tests/test_speedometer_element.py.

Renders the clip (12 s, 480x270, 12.5 fps, cuboid vehicles), runs ``filesrc ! decodebin ! videoconvert !
<detector> ! speedometer calibration-file=<true calibration>`` with the true boxes (test element tcgtdetect) and
with vehicledetect's background detector, and prints each chain's errors against the rendered ground truth::

    .venv/bin/python benchmarks/speedometer_errors.py
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests import test_speedometer_element as T  # noqa: E402  (the helpers and element registration of the tests)
from tests.conftest import CUBOID_SCENE  # noqa: E402  (the clip the tests render)

from gst_trafficcal.gst.element import register_plugin_file  # noqa: E402
from gst_trafficcal.synth.generate import generate  # noqa: E402
from gst_trafficcal.synth.scenario import scenario_from_dict  # noqa: E402
from gst_trafficcal.synth.traffic import cuboid_models  # noqa: E402


def main() -> None:
    for name in ("speedometer.py", "tracker.py", "vehicledetect.py"):
        register_plugin_file(T.ELEMENTS / name)
    register_plugin_file(T.TEST_PLUGINS / "tcgtdetect.py")
    work = Path(tempfile.mkdtemp(prefix="speedometer-errors-"))
    clip = work / "clip"
    generate(scenario_from_dict(CUBOID_SCENE), clip, box_vehicles=True, model_factory=cuboid_models())
    for name, chain in (("true boxes", T.detector(clip)), ("vehicledetect", "vehicledetect")):
        _, events, results = T.measure(clip, work / name.replace(" ", "_"), chain,
                                       f"calibration-file={clip / 'calibration.json'}")
        e = T.gt_speed_errors(clip, events, results)
        print(f"{name}: {len(e)} vehicles measured, |error| median {np.median(np.abs(e)):.2f} km/h, "
              f"mean {np.mean(np.abs(e)):.2f}, max {np.abs(e).max():.2f}; errors {np.round(np.sort(e), 2).tolist()}")


if __name__ == "__main__":
    main()
