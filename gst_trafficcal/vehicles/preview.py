"""Small moderngl (EGL, headless) preview renderer of vehicle meshes: shaded three-quarter views with part
colours, and a contact sheet of several meshes — for looking at the catalogue, not for scenes (the scene
renderer is :mod:`gst_trafficcal.synth.render`)."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from .mesh import VehicleMesh
from .parts import PART_BODY, PART_HEADLIGHT, PART_PLATE, PART_TAILLIGHT, PART_TRIM, PART_WHEEL, PART_WINDOW

PART_COLOURS = {PART_WINDOW: (0.08, 0.12, 0.17), PART_WHEEL: (0.04, 0.04, 0.04), PART_HEADLIGHT: (1.0, 0.97, 0.8),
                PART_TAILLIGHT: (0.75, 0.04, 0.03), PART_PLATE: (0.93, 0.93, 0.9), PART_TRIM: (0.12, 0.12, 0.13)}

_VERT = """
#version 330
in vec3 in_pos; in vec3 in_normal; in vec3 in_colour;
uniform mat4 mvp;
out vec3 v_normal; out vec3 v_colour;
void main() { gl_Position = mvp * vec4(in_pos, 1.0); v_normal = in_normal; v_colour = in_colour; }
"""
_FRAG = """
#version 330
in vec3 v_normal; in vec3 v_colour;
uniform vec3 light;
out vec4 colour;
void main() {
    float d = abs(dot(normalize(v_normal), light));
    colour = vec4(v_colour * (0.35 + 0.65 * d), 1.0);
}
"""


def _look_at(eye: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    f = target - eye
    f /= np.linalg.norm(f)
    s = np.cross(f, up)
    s /= np.linalg.norm(s)
    u = np.cross(s, f)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = s, u, -f
    m[:3, 3] = -m[:3, :3] @ eye
    return m


def _perspective(fovy_deg: float, aspect: float, near: float, far: float) -> np.ndarray:
    t = 1.0 / np.tan(np.radians(fovy_deg) / 2)
    return np.array([[t / aspect, 0, 0, 0], [0, t, 0, 0], [0, 0, (far + near) / (near - far), 2 * far * near / (near - far)],
                     [0, 0, -1, 0]])


def render_views(meshes: Sequence[VehicleMesh], size: tuple[int, int] = (320, 240), azimuth: float = 35.0,
                 elevation: float = 18.0) -> list[np.ndarray]:
    """RGB uint8 images (h, w, 3) of each mesh seen from the front-left (azimuth from the +x axis towards +y,
    degrees) on a light background, framed to the mesh's size."""
    import moderngl

    ctx = moderngl.create_standalone_context(backend="egl")
    try:
        prog = ctx.program(vertex_shader=_VERT, fragment_shader=_FRAG)
        fbo = ctx.framebuffer(ctx.renderbuffer(size, samples=0), ctx.depth_renderbuffer(size))
        fbo.use()
        ctx.enable(moderngl.DEPTH_TEST)
        out = []
        for mesh in meshes:
            tri = mesh.vertices[mesh.faces].astype(np.float64)  # (M, 3, 3): flat shading, one normal per face
            n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
            col = np.array([PART_COLOURS.get(int(p), mesh.body_colour) for p in range(8)])[
                np.minimum(mesh.parts, 7)]
            col[mesh.parts == PART_BODY] = mesh.body_colour
            data = np.concatenate([tri, np.repeat(n[:, None], 3, 1), np.repeat(col[:, None], 3, 1)], axis=2)
            vbo = ctx.buffer(data.astype(np.float32).tobytes())
            vao = ctx.vertex_array(prog, [(vbo, "3f 3f 3f", "in_pos", "in_normal", "in_colour")])
            lo, hi = mesh.bounds()
            centre = (lo + hi) / 2
            radius = float(np.linalg.norm(hi - lo)) / 2
            a, e = np.radians(azimuth), np.radians(elevation)
            eye = centre + 3.8 * radius * np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
            mvp = _perspective(25.0, size[0] / size[1], 0.1 * radius, 10 * radius) @ _look_at(eye, centre)
            prog["mvp"].write(mvp.T.astype(np.float32).tobytes())
            light = np.array([0.3, 0.5, 0.8])
            prog["light"].value = tuple(light / np.linalg.norm(light))
            fbo.clear(0.93, 0.94, 0.95, 1.0)
            vao.render()
            img = np.frombuffer(fbo.read(components=3), np.uint8).reshape(size[1], size[0], 3)[::-1]
            out.append(img.copy())
            vao.release()
            vbo.release()
        return out
    finally:
        ctx.release()


def contact_sheet(meshes: Sequence[VehicleMesh], labels: Sequence[str], path: str | Path, columns: int = 4,
                  size: tuple[int, int] = (320, 240)) -> Path:
    """Write a PNG grid of the meshes' previews with their labels."""
    import cv2

    from ..fileio import atomic_write_image

    views = render_views(meshes, size)
    rows = -(-len(views) // columns)
    sheet = np.full((rows * size[1], columns * size[0], 3), 255, np.uint8)
    for i, (img, label) in enumerate(zip(views, labels)):
        r, c = divmod(i, columns)
        tile = img.copy()
        cv2.putText(tile, label, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (20, 20, 20), 1, cv2.LINE_AA)
        sheet[r * size[1]:(r + 1) * size[1], c * size[0]:(c + 1) * size[0]] = tile
    path = Path(path)
    atomic_write_image(path, cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR), "contact sheet")  # whole, or an InputError
    return path
