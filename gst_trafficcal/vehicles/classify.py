"""Vehicle class from measured 3D dimensions: car, van, bus, truck or motorcycle.

The default detectors (``vehicleseg``, the background detector) find vehicles but do not tell a bus from a car;
they label every vehicle "car".  Once a calibration with a scale is known the tracker's 3D boxes give each
vehicle's length, width and height in metres, and the catalogue's dimension distributions per body style
(:func:`~gst_trafficcal.vehicles.catalogue.style_distributions`, the same ones ``trafficcal synth`` draws from)
say which class such a vehicle most likely is: per class the best of its styles (and style variants, e.g. rigid
and articulated trucks) by a normal likelihood in log dimensions, whose spread is the style's own spread plus the
3D boxes' measurement error (:data:`MEASUREMENT_NOISE`).  Equal priors: a class is not preferred because it is
common.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

#: the label each catalogue body style is reported as (COCO's vehicle names, plus "van")
LABEL_OF_STYLE: dict[str, str] = {"sedan": "car", "estate": "car", "hatchback": "car", "suv": "car", "van": "van",
                                  "bus": "bus", "truck": "truck", "motorcycle": "motorcycle"}
#: detector labels that carry no class of their own (a class-agnostic detector's), refined by the dimensions
GENERIC_LABELS: frozenset[str] = frozenset({"", "car", "vehicle"})
#: relative error (robust standard deviation of log(measured / true)) of a track's median 3D-box length, width and
#: height: vehicleseg's outlines and the true camera on the ten synth presets (docs/tracking.md, "Vehicle classes")
MEASUREMENT_NOISE: tuple[float, float, float] = (0.11, 0.13, 0.065)
#: dimensions further than this (standard deviations) from every style of the best class: no class is claimed
MAX_Z = 4.0
#: how much more likely (log) than the next class a motorcycle's dimensions must be for the class to be claimed: a
#: car seen only in part or from afar measures short and narrow, never long, so the smallest class is where such
#: cars land (kraten_cars.mp4's far-side cars: margins 1–9); a motorcycle drawn from the catalogue with the
#: measurement noise has 10 or more 99.4 % of the time (docs/tracking.md "Vehicle classes", stop 57)
MOTORCYCLE_MARGIN = 10.0


@dataclass(frozen=True)
class SizeClass:
    """The class of one vehicle: ``label`` (car, van, bus, truck, motorcycle), the catalogue ``style`` that
    explains its dimensions best, and ``margin``: how much more likely that is than the next class (log)."""

    label: str
    style: str
    margin: float
    worst_z: float  # the largest of the three dimensions' deviations from that style, in standard deviations


@lru_cache(maxsize=4)
def _components(catalogue: str | None) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """(styles (C,), log mean dimensions (C, 3), relative spread (C, 3)) of every style and style variant."""
    from .catalogue import style_distributions

    names, means, spreads = [], [], []
    for name, dist in style_distributions(catalogue).items():
        own = [dist] + [v[1] for v in dist.variants.values() if v[1] is not None]
        for d in own:
            names.append(name)
            means.append(np.log(d.mean))
            spreads.append(np.asarray(d.std, float) / np.asarray(d.mean, float))
    return tuple(names), np.array(means), np.array(spreads)


def classify_dimensions(dims: np.ndarray, noise: tuple[float, float, float] = MEASUREMENT_NOISE,
                        catalogue: str | None = None) -> list[SizeClass]:
    """Classes of vehicles with dimensions ``dims`` (N, 3: length, width, height in metres)."""
    dims = np.asarray(dims, np.float64).reshape(-1, 3)
    if np.any(~np.isfinite(dims) | (dims <= 0)):
        raise ValueError("vehicle dimensions must be positive metres")
    names, mu, spread = _components(catalogue)
    sigma = np.sqrt(spread ** 2 + np.asarray(noise, np.float64) ** 2)  # (C, 3)
    z = (np.log(dims)[:, None, :] - mu[None]) / sigma[None]  # (N, C, 3)
    ll = -0.5 * np.sum(z * z, axis=2) - np.sum(np.log(sigma), axis=1)[None]  # (N, C)
    named = [LABEL_OF_STYLE.get(n, n) for n in names]  # a style a user added is reported by its own name
    labels = sorted(set(named))
    of = np.array([labels.index(n) for n in named])
    per = np.full((len(dims), len(labels)), -np.inf)
    for k in range(len(labels)):
        per[:, k] = ll[:, of == k].max(axis=1)
    order = np.argsort(-per, axis=1)
    out = []
    for i in range(len(dims)):
        best, second = order[i, 0], order[i, 1]
        members = np.flatnonzero(of == best)
        k = members[np.argmax(ll[i, members])]
        out.append(SizeClass(labels[best], names[k], float(per[i, best] - per[i, second]),
                             float(np.max(np.abs(z[i, k])))))
    return out


def refined_label(detector_label: str, size_class: SizeClass | None, max_z: float = MAX_Z) -> str:
    """The label to report: a detector's own class (bus, truck, motorcycle, ...) is kept; a class-agnostic one
    (:data:`GENERIC_LABELS`) becomes the class the dimensions give, when they are known and that class explains
    them (no dimension more than ``max_z`` standard deviations off: a car measured half its length is no
    motorcycle) — a motorcycle only when its dimensions say so by :data:`MOTORCYCLE_MARGIN`."""
    if size_class is None or detector_label not in GENERIC_LABELS or size_class.worst_z > max_z:
        return detector_label
    if size_class.label == "motorcycle" and size_class.margin < MOTORCYCLE_MARGIN:
        return detector_label
    return size_class.label
