"""The vehicle catalogue: named real models with their published dimensions (and the source of every figure),
plus per-body-style dimension distributions, read from ``models3d/catalogue.yaml`` (the repository's, or the copy an
installed wheel carries: gst_trafficcal.resources).

The synthetic renderer draws vehicles from it and bbscale aligns the same models with detected vehicles, so
both sides of the scale estimation agree on what an "Octavia combi" is."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path

import numpy as np
import yaml

from ..errors import InputError
from ..resources import shipped

BODY_STYLES: tuple[str, ...] = ("sedan", "estate", "hatchback", "suv", "van", "bus", "truck", "motorcycle")
DEFAULT_CATALOGUE = shipped("models3d") / "catalogue.yaml"
_DIMS = ("length", "width", "height")


@dataclass(frozen=True)
class VehicleModel:
    """One vehicle type with its outer dimensions in metres (length without mirrors, height unladen) and
    wheelbase; ``sources`` names the document each figure comes from; ``mesh`` an optional mesh file
    (GLB/OBJ/STL) rescaled to these dimensions, else the body style's procedural mesh is used.  ``variant``
    refines the procedural shape within a style (e.g. "liftback" or "notchback" for a sedan, "articulated" for
    a truck)."""

    name: str
    body_style: str
    length: float
    width: float
    height: float
    wheelbase: float
    sources: dict = field(default_factory=dict, compare=False, hash=False)
    mesh: Path | None = None
    mesh_axes: tuple[str, str] | None = None  # (forward, up) axes of the mesh file, e.g. ("+z", "+y")
    variant: str = ""
    description: str = ""


@dataclass(frozen=True)
class DimensionDistribution:
    """Per-class dimensions: independent normals on length and the width/height deviations correlated with
    length (bigger cars are also wider and, slightly, taller), clipped to [min, max]; wheelbase = ratio x length."""

    body_style: str
    mean: tuple[float, float, float]  # length, width, height
    std: tuple[float, float, float]
    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    corr: tuple[float, float]  # correlation of width and height with length
    wheelbase_ratio: tuple[float, float]  # mean, std
    # variant -> (probability, its own distribution or None to share this one)
    variants: dict = field(default_factory=dict, compare=False, hash=False)

    def sample(self, rng: np.random.Generator) -> tuple[float, float, float, float, str]:
        """(length, width, height, wheelbase, variant) drawn from the distribution (variant first, then its
        own dimensions when it overrides them)."""
        if self.variants:
            names = list(self.variants)
            p = np.array([self.variants[n][0] for n in names], float)
            variant = names[int(rng.choice(len(names), p=p / p.sum()))]
            sub = self.variants[variant][1]
            if sub is not None:
                return (*sub.sample(rng)[:4], variant)
            return (*self._sample_dims(rng), variant)
        return (*self._sample_dims(rng), "")

    def _sample_dims(self, rng: np.random.Generator) -> tuple[float, float, float, float]:
        z = rng.standard_normal(3)
        cw, ch = self.corr
        zw = cw * z[0] + np.sqrt(max(0.0, 1 - cw * cw)) * z[1]
        zh = ch * z[0] + np.sqrt(max(0.0, 1 - ch * ch)) * z[2]
        dims = np.array(self.mean) + np.array(self.std) * np.array([z[0], zw, zh])
        dims = np.clip(dims, self.lo, self.hi)
        ratio = float(np.clip(rng.normal(*self.wheelbase_ratio), 0.15, 0.85))
        return float(dims[0]), float(dims[1]), float(dims[2]), ratio * float(dims[0])


def _num(where: str, value, lo: float = 0.0, hi: float = 100.0) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{where} must be a number, got {value!r}") from None
    if not lo < v <= hi:
        raise InputError(f"{where} = {v:g} is out of range ({lo:g}, {hi:g}] metres")
    return v


def _parse_model(path: Path, name: str, d) -> VehicleModel:
    where = f"{path}: models.{name}"
    if not isinstance(d, dict):
        raise InputError(f"{where} must be a mapping")
    style = d.get("body_style")
    if style not in BODY_STYLES:
        raise InputError(f"{where}.body_style {style!r} is not one of {', '.join(BODY_STYLES)}")
    for k in (*_DIMS, "wheelbase"):
        if k not in d:
            raise InputError(f"{where} lacks '{k}'")
    length, width, height = (_num(f"{where}.{k}", d[k]) for k in _DIMS)
    wheelbase = _num(f"{where}.wheelbase", d["wheelbase"])
    if wheelbase >= length:
        raise InputError(f"{where}.wheelbase {wheelbase:g} must be shorter than the length {length:g}")
    sources = d.get("sources") or {}
    if not isinstance(sources, dict):
        raise InputError(f"{where}.sources must be a mapping figure -> source")
    mesh = d.get("mesh")
    if mesh:
        mesh = Path(mesh)
        if not mesh.is_absolute():
            mesh = (path.parent / mesh).resolve()
    axes = d.get("mesh_axes")
    if axes is not None:
        if not (isinstance(axes, dict) and {"forward", "up"} <= set(axes)):
            raise InputError(f"{where}.mesh_axes must be a mapping with 'forward' and 'up' (e.g. +z, +y)")
        axes = (str(axes["forward"]), str(axes["up"]))
    return VehicleModel(name=name, body_style=style, length=length, width=width, height=height,
                        wheelbase=wheelbase, sources=dict(sources), mesh=mesh or None, mesh_axes=axes,
                        variant=str(d.get("variant") or ""), description=str(d.get("description") or ""))


def _triple(where: str, d: dict, key: str) -> tuple[float, float, float]:
    lo = -1e-12 if key == "std" else 0.0
    return tuple(_num(f"{where}.{k}.{key}", (d.get(k) or {}).get(key), lo) for k in _DIMS)  # type: ignore[return-value]


def _parse_style(path: Path, name: str, d, variant: str = "") -> DimensionDistribution:
    where = f"{path}: body_styles.{name}" + (f".variants.{variant}" if variant else "")
    if name not in BODY_STYLES:
        raise InputError(f"{where}: unknown body style (valid: {', '.join(BODY_STYLES)})")
    if not isinstance(d, dict):
        raise InputError(f"{where} must be a mapping")
    for k in _DIMS:
        if not isinstance(d.get(k), dict):
            raise InputError(f"{where}.{k} must be a mapping with mean, std, min, max")
    wb = d.get("wheelbase_ratio") or {}
    corr = d.get("correlation") or {}
    variants = {}
    for vname, vd in ({} if variant else (d.get("variants") or {})).items():
        if isinstance(vd, (int, float)):
            variants[str(vname)] = (float(vd), None)
            continue
        if not isinstance(vd, dict) or "p" not in vd:
            raise InputError(f"{where}.variants.{vname} must be a probability or a mapping with 'p'")
        own = {k: v for k, v in vd.items() if k != "p"}
        sub = _parse_style(path, name, {**{k: v for k, v in d.items() if k != "variants"}, **own}, str(vname)) \
            if own else None
        variants[str(vname)] = (float(vd["p"]), sub)
    return DimensionDistribution(
        body_style=name, mean=_triple(where, d, "mean"), std=_triple(where, d, "std"), lo=_triple(where, d, "min"),
        hi=_triple(where, d, "max"),
        corr=(float(corr.get("width", 0.0)), float(corr.get("height", 0.0))),
        wheelbase_ratio=(_num(f"{where}.wheelbase_ratio.mean", wb.get("mean"), 0, 1), float(wb.get("std", 0.0))),
        variants=variants)


@dataclass(frozen=True)
class Catalogue:
    models: dict[str, VehicleModel]
    styles: dict[str, DimensionDistribution]


@lru_cache(maxsize=8)
def _load(path: Path) -> Catalogue:
    if not path.is_file():
        raise InputError(f"vehicle catalogue {path} not found")
    try:
        doc = yaml.safe_load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise InputError(f"vehicle catalogue {path} is not valid YAML: {str(exc).splitlines()[0]}") from None
    if not isinstance(doc, dict):
        raise InputError(f"vehicle catalogue {path} must be a mapping with 'models' and 'body_styles'")
    models = {str(k): _parse_model(path, str(k), v) for k, v in (doc.get("models") or {}).items()}
    styles = {str(k): _parse_style(path, str(k), v) for k, v in (doc.get("body_styles") or {}).items()}
    return Catalogue(models, styles)


def load_catalogue(path: str | Path | None = None) -> dict[str, VehicleModel]:
    """Named vehicle models by name (default: the shipped ``models3d/catalogue.yaml``).  Raises InputError
    naming the file for a missing or malformed catalogue."""
    return dict(_load(Path(path or DEFAULT_CATALOGUE).resolve()).models)


def style_distributions(path: str | Path | None = None) -> dict[str, DimensionDistribution]:
    """The per-body-style dimension distributions of a catalogue."""
    return dict(_load(Path(path or DEFAULT_CATALOGUE).resolve()).styles)


def sample_model(body_style: str, rng: np.random.Generator, path: str | Path | None = None) -> VehicleModel:
    """A generic vehicle of ``body_style`` with dimensions drawn from the class distribution."""
    styles = _load(Path(path or DEFAULT_CATALOGUE).resolve()).styles
    if body_style not in styles:
        raise InputError(f"unknown body style {body_style!r} (valid: {', '.join(styles)})")
    length, width, height, wheelbase, variant = styles[body_style].sample(rng)
    return VehicleModel(name=f"generic_{body_style}", body_style=body_style, length=length, width=width,
                        height=height, wheelbase=wheelbase, sources={"all": "sampled from the body-style distribution"},
                        variant=variant)


def with_dimensions(model: VehicleModel, length: float, width: float, height: float) -> VehicleModel:
    """A copy of ``model`` at other outer dimensions (wheelbase scaled with the length)."""
    return replace(model, length=length, width=width, height=height, wheelbase=model.wheelbase * length / model.length)
