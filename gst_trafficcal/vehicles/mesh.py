"""Vehicle meshes in the vehicle frame (x forward, y left, z up, origin at the centre of the bottom face of the
bounding box): procedural body styles, or mesh files (GLB/OBJ/STL through trimesh) rescaled per axis to real
dimensions."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..errors import InputError
from .catalogue import VehicleModel
from .parts import (PART_BODY, PART_HEADLIGHT, PART_NAMES, PART_PLATE, PART_TAILLIGHT, PART_TRIM, PART_WHEEL,
                    PART_WINDOW)
from .procedural import body_colour, procedural_pieces, snap_to_box

__all__ = ["VehicleMesh", "procedural_mesh", "load_mesh_file", "mesh_for", "PART_BODY", "PART_WINDOW",
           "PART_WHEEL", "PART_HEADLIGHT", "PART_TAILLIGHT", "PART_PLATE", "PART_TRIM", "PART_NAMES"]


@dataclass
class VehicleMesh:
    """Triangles of one vehicle: ``vertices`` (N,3) float32 metres, ``faces`` (M,3) uint32, ``parts`` (M,) uint8
    part id per face, ``body_colour`` RGB in [0, 1]."""

    vertices: np.ndarray
    faces: np.ndarray
    parts: np.ndarray
    body_colour: tuple[float, float, float]

    def bounds(self) -> np.ndarray:
        """(2, 3) axis-aligned bounds: [[xmin, ymin, zmin], [xmax, ymax, zmax]]."""
        return np.stack([self.vertices.min(0), self.vertices.max(0)])

    @property
    def size(self) -> np.ndarray:
        b = self.bounds()
        return b[1] - b[0]


def _make(V: np.ndarray, F: np.ndarray, P: np.ndarray, colour) -> VehicleMesh:
    return VehicleMesh(np.ascontiguousarray(V, np.float32), np.ascontiguousarray(F, np.uint32),
                       np.ascontiguousarray(P, np.uint8), tuple(float(c) for c in colour))


def procedural_mesh(model: VehicleModel, rng: np.random.Generator) -> VehicleMesh:
    """The procedural mesh of the model's body style at its exact dimensions and wheelbase, in a random colour."""
    V, F, P = procedural_pieces(model.body_style, model.variant, model.length, model.width, model.height,
                                model.wheelbase)
    return _make(V, F, P, body_colour(model.body_style, rng))


# --------------------------------------------------------------------------- mesh files


def _file_geometry(path: Path):
    """(vertices, faces, parts, forward/up axes guess) of a mesh file in its own axes, via trimesh."""
    import trimesh

    if not path.is_file():
        raise InputError(f"vehicle mesh {path} not found")
    try:
        scene = trimesh.load(str(path), force="scene")
    except Exception as exc:  # trimesh raises many types for corrupt files
        raise InputError(f"vehicle mesh {path} cannot be read: {type(exc).__name__}: {exc}".splitlines()[0]) from None
    Vs, Fs, Ps, off = [], [], [], 0
    try:
        nodes = list(scene.graph.nodes_geometry)
    except Exception as exc:
        raise InputError(f"vehicle mesh {path} cannot be read: {exc}".splitlines()[0]) from None
    for node in nodes:
        T, gname = scene.graph[node]
        geom = scene.geometry.get(gname)
        if geom is None or not hasattr(geom, "faces") or len(geom.faces) == 0:
            continue
        V = np.asarray(geom.vertices, np.float64) @ T[:3, :3].T + T[:3, 3]
        F = np.asarray(geom.faces, np.int64)
        Vs.append(V)
        Fs.append(F + off)
        Ps.append(_face_parts(node, gname, geom))
        off += len(V)
    if not Vs:
        raise InputError(f"vehicle mesh {path} holds no triangles")
    V, F, P = np.concatenate(Vs), np.concatenate(Fs), np.concatenate(Ps)
    # lamps sit at the ends of the vehicle: a lamp colour spread over its middle is the paint (a yellow taxi)
    ax = int(np.argmax(V.max(0) - V.min(0)))
    centre, half = (V[:, ax].max() + V[:, ax].min()) / 2, (V[:, ax].max() - V[:, ax].min()) / 2
    off = np.abs(V[F].mean(1)[:, ax] - centre) / max(half, 1e-9)
    for part in (PART_HEADLIGHT, PART_TAILLIGHT):
        sel = P == part
        if sel.any() and np.median(off[sel]) < 0.6:
            P[sel] = PART_BODY
    # glass covering more of the body than the paint is the paint
    if (P == PART_WINDOW).sum() > (P == PART_BODY).sum():
        P[P == PART_WINDOW] = PART_BODY
    return V, F, P


_NAME_PARTS = (("wheel", PART_WHEEL), ("tyre", PART_WHEEL), ("tire", PART_WHEEL), ("window", PART_WINDOW),
               ("glass", PART_WINDOW), ("headlight", PART_HEADLIGHT), ("taillight", PART_TAILLIGHT),
               ("plate", PART_PLATE), ("grill", PART_TRIM))


def _face_parts(node: str, gname: str, geom) -> np.ndarray:
    """Part id per face from the node / geometry name, else from the face colours (texture palette or vertex
    colours): dark blue-grey glass, white-yellow headlamps, red tail lamps, near-black rubber/trim."""
    n = len(geom.faces)
    key = f"{node} {gname}".lower()
    for word, part in _NAME_PARTS:
        if word in key:
            return np.full(n, part, np.uint8)
    rgb = _face_colours(geom)
    if rgb is None:
        return np.full(n, PART_BODY, np.uint8)
    return classify_colours(rgb)


def classify_colours(rgb: np.ndarray) -> np.ndarray:
    """Part ids for face colours (M,3) in [0, 1] (the conventions of low-poly kits such as Kenney's): saturated
    red -> tail light, saturated yellow or pure white -> headlight, very light blue-white -> glass, near-black
    and mid-grey unsaturated (bumpers, sills, underbody, grilles) -> trim, everything else body paint."""
    r, g, b = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    mx, mn = rgb.max(1), rgb.min(1)
    sat = (mx - mn) / np.maximum(mx, 1e-6)
    parts = np.full(len(rgb), PART_BODY, np.uint8)
    parts[(mx < 0.12) | ((sat < 0.3) & (mx < 0.6))] = PART_TRIM
    parts[(mn > 0.8) & (b >= 0.97) & (b > r + 0.03)] = PART_WINDOW
    parts[(r > 0.8) & (g < 0.3) & (b < 0.3)] = PART_TAILLIGHT
    parts[((r > 0.9) & (g > 0.7) & (b < 0.35)) | (mn > 0.97)] = PART_HEADLIGHT
    return parts


def _face_colours(geom) -> np.ndarray | None:
    vis = getattr(geom, "visual", None)
    if vis is None:
        return None
    try:
        if getattr(vis, "kind", None) == "texture" and getattr(vis, "uv", None) is not None:
            img = getattr(vis.material, "baseColorTexture", None) or getattr(vis.material, "image", None)
            if img is None:
                return None
            tex = np.asarray(img.convert("RGB"), np.float64) / 255.0
            uv = np.asarray(vis.uv, np.float64)[np.asarray(geom.faces)].mean(1)
            h, w = tex.shape[:2]
            px = np.clip((uv[:, 0] % 1.0) * w, 0, w - 1).astype(int)
            py = np.clip((1 - uv[:, 1] % 1.0) * h, 0, h - 1).astype(int)
            rgb = tex[py, px]
            factor = getattr(vis.material, "baseColorFactor", None)
            if factor is not None:
                rgb = rgb * np.asarray(factor[:3], np.float64) / (255.0 if np.max(factor) > 1 else 1.0)
            return rgb
        fc = np.asarray(vis.face_colors, np.float64)[:, :3] / 255.0
        return fc
    except Exception:
        return None


_AXES = {"+x": (1.0, 0, 0), "-x": (-1.0, 0, 0), "+y": (0, 1.0, 0), "-y": (0, -1.0, 0), "+z": (0, 0, 1.0),
         "-z": (0, 0, -1.0)}


def parse_axis(name: str) -> np.ndarray:
    """"+z" -> (0, 0, 1) etc."""
    key = str(name).strip().lower()
    if key in ("x", "y", "z"):
        key = "+" + key
    if key not in _AXES:
        raise InputError(f"mesh axis {name!r} must be one of {', '.join(_AXES)}")
    return np.array(_AXES[key], np.float64)


def guess_axes(path: Path, V: np.ndarray, parts: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Forward and up axes of a mesh in file coordinates.  Up: +Y for glTF/GLB (the format says so) and OBJ (by
    convention), +Z for STL/PLY/OFF (CAD convention).  Forward: the longer horizontal extent, signed towards the
    headlight-coloured faces (or away from the tail lights); the Kenney car kit (Y-up, front at +Z: its
    "wheel-front-*" nodes and yellow headlamps sit at +Z) comes out as forward = +Z."""
    up = np.array([0.0, 0.0, 1.0]) if path.suffix.lower() in (".stl", ".ply", ".off") else np.array([0.0, 1.0, 0.0])
    horiz = [i for i in range(3) if up[i] == 0]
    ext = V.max(0) - V.min(0)
    ax = horiz[int(np.argmax(ext[horiz]))]
    centre = (V.max(0) + V.min(0)) / 2
    fc = V[F].mean(1)[:, ax] - centre[ax]
    head, tail = parts == PART_HEADLIGHT, parts == PART_TAILLIGHT
    score = (fc[head].mean() if head.any() else 0.0) - (fc[tail].mean() if tail.any() else 0.0)
    fwd = np.zeros(3)
    fwd[ax] = 1.0 if score >= 0 else -1.0
    return fwd, up


@lru_cache(maxsize=64)
def _load_file_cached(path: str, mtime: float, axes: tuple | None):
    if axes is not None:  # a wrong axis spec is reported before (and whether or not) the file reads
        fwd, up = (parse_axis(a) for a in axes)
        if abs(float(fwd @ up)) > 1e-9:
            raise InputError(f"vehicle mesh {path}: forward axis and up axis must differ")
    V, F, P = _file_geometry(Path(path))
    if axes is None:
        fwd, up = guess_axes(Path(path), V, P, F)
    left = np.cross(up, fwd)
    R = np.stack([fwd, left, up])  # rows: our x, y, z in file coordinates
    return V @ R.T, F, P


def load_mesh_file(path: str | Path, length: float, width: float, height: float,
                   axes: tuple | None = None, colour=(0.6, 0.6, 0.62)) -> VehicleMesh:
    """A GLB/OBJ/STL (anything trimesh reads) turned into our frame and rescaled per axis to exactly
    length x width x height.  ``axes`` = (forward, up) in file coordinates such as ("+z", "+y"), else guessed
    (see ``guess_axes``).
    Raises InputError naming a missing or unreadable file."""
    p = Path(path)
    try:
        mtime = p.stat().st_mtime
    except OSError:
        raise InputError(f"vehicle mesh {p} not found") from None
    key = None if axes is None else (str(axes[0]), str(axes[1]))
    V, F, P = _load_file_cached(str(p.resolve()), mtime, key)
    return _make(snap_to_box(V, length, width, height), F, P, colour)


def mesh_for(model: VehicleModel, rng: np.random.Generator) -> VehicleMesh:
    """The model's mesh file rescaled to its dimensions when it has one, else its procedural mesh; either way in
    a random body colour drawn from ``rng``."""
    if model.mesh is not None:
        return load_mesh_file(model.mesh, model.length, model.width, model.height, axes=model.mesh_axes,
                              colour=body_colour(model.body_style, rng))
    return procedural_mesh(model, rng)
