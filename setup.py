"""The wheel's packages: the library, plus the GStreamer element files and the vehicle catalogue mapped into it.

They stay in the repository where they are (``elements/python/*.py``, ``models3d/``: one copy of each file) and are
installed as ``gst_trafficcal/elements/python/`` and ``gst_trafficcal/models3d/``, where an installed package finds
them (gst_trafficcal.resources). Everything else is in pyproject.toml.
"""

from setuptools import find_namespace_packages, setup

MAPPED = {"gst_trafficcal.elements": "elements", "gst_trafficcal.models3d": "models3d"}

setup(
    packages=find_namespace_packages(include=["gst_trafficcal*"], exclude=["*__pycache__*"]) + [
        "gst_trafficcal.elements.python", "gst_trafficcal.models3d"],
    package_dir=MAPPED,
)
