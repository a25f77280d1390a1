"""Headless OpenGL renderer of the road scene and vehicles (moderngl, EGL, runs on Mesa llvmpipe).

Per frame the work is: a copy restoring the cached static scene (colour and depth, rendered once) into a 4x
multisampled target where the previous frame drew, one draw call for the planar and contact shadows of all
vehicles, one for headlight beams at night, one for all vehicles (their triangles merged into one vertex
buffer), a resolve of the multisampled colour where vehicles are or were (anti-aliased vehicle and shadow
edges, as a real camera's optics and sensor give; aliased staircase edges biased edgelet vanishing points),
and its read-back.  A vehicle-ID mask is drawn by a second, single-sampled pass of the same triangles with a
trivial shader into a one-channel target over the static depth, read back too (exact: each pixel holds the
vehicle seen at its centre, IDs never blend; used for visibility and by the exactness tests).
llvmpipe runs every branch of a shader for every fragment (masked), so the scene shader is compiled in
variants: one per static material (the static scene is drawn run by run) and one with the vehicle materials
only.  Full-screen shader passes cost ~10 ms at 1080p on llvmpipe, so the imaging chain runs in OpenCV
instead.  Textures are procedural noise made with numpy; materials are chosen per vertex.
"""

from __future__ import annotations

import functools
import itertools
from dataclasses import dataclass

import numpy as np

from .camera import SynthCamera
from .scenario import LightingSpec
from .scene import (MAT_BODY, MAT_GLASS, MAT_HEADLIGHT, MAT_PLATE, MAT_RUBBER, MAT_TAILLIGHT, MAT_TRIM)

_VERT = """
#version 330
uniform mat4 mvp;
in vec3 in_pos; in vec3 in_normal; in vec3 in_col; in float in_mat; in float in_id;
out vec3 v_pos; out vec3 v_n; out vec3 v_col; flat out float v_mat; flat out float v_id;
void main() {
    v_pos = in_pos; v_n = in_normal; v_col = in_col; v_mat = in_mat; v_id = in_id;
    gl_Position = mvp * vec4(in_pos, 1.0);
}
"""

_FRAG = """
#version 330
uniform sampler2D noise;
uniform vec3 sun_dir; uniform vec3 sun_col; uniform vec3 amb_col; uniform vec3 sky_col; uniform vec3 zenith_col;
uniform vec3 cam_pos; uniform float haze; uniform float lamps_on; uniform float lights_on;
uniform float lamp_spacing; uniform float lamp_x0; uniform float lamp_y;
uniform float lane_w; uniform float median_half; uniform float carriage_w;
uniform float curve_start; uniform float curve_inv_r;
uniform float surface_tex; uniform float joints;
float bend(float x) { float d = max(x - curve_start, 0.0); return d * d * 0.5 * curve_inv_r; }
in vec3 v_pos; in vec3 v_n; in vec3 v_col; flat in float v_mat; flat in float v_id;
layout(location = 0) out vec4 f_col;

float nz(vec2 p, int c) { return texture(noise, p)[c]; }

vec3 lamp_light(vec3 p, vec3 n) {
    if (lamps_on < 0.5 || lamp_spacing <= 0.0) return vec3(0.0);
    float k = floor((p.x - lamp_x0) / lamp_spacing + 0.5);
    vec3 acc = vec3(0.0);
    for (int j = -1; j <= 1; j++) {
        float lx = lamp_x0 + (k + float(j)) * lamp_spacing;
        for (int s = -1; s <= 1; s += 2) {
            vec3 d = vec3(lx, float(s) * lamp_y + bend(lx), 9.7) - p;
            float r2 = dot(d, d);
            acc += vec3(1.0, 0.78, 0.5) * 45.0 * max(dot(n, normalize(d)), 0.0) / (r2 + 4.0);
        }
    }
    return acc;
}

void main() {
#ifdef ONLY_MAT
    const int mat = ONLY_MAT;  // one material per draw: the compiler drops the other materials' branches
#else
    int mat = int(v_mat + 0.5);
#endif
    vec3 n = normalize(v_n);
    vec3 view = normalize(cam_pos - v_pos);
    if (dot(n, view) < 0.0) n = -n;
    vec3 base = v_col;
    float spec = 0.0; float shin = 16.0; vec3 emit = vec3(0.0); float refl = 0.0;
    vec2 p = v_pos.xy;
#ifndef VEHICLES_ONLY
    // the static scene's materials (the vehicles' program leaves them out: llvmpipe runs every branch)
    if (mat == 1 && surface_tex == 1.0 && joints == 0.0) {   // asphalt: grain, patches, longitudinal wear
        float g = nz(p * 0.9, 0) * 0.6 + nz(p * 0.23, 0) * 0.4;
        float patch = nz(p * 0.013, 1);
        float wear = nz(vec2(p.x * 0.004, p.y * 0.35), 2);
        base *= 0.70 + 0.45 * g;
        base *= 0.80 + 0.40 * patch;
        base *= 0.90 + 0.20 * wear;
        base += vec3(0.03) * smoothstep(0.7, 0.9, nz(p * 0.05, 3));
        // lanes: polished lighter wheel paths, a dark oil strip in the middle of each lane
        float a = abs(p.y - bend(p.x)) - median_half;
        if (a > 0.0 && a < carriage_w) {
            float d = abs(fract(a / lane_w) - 0.5) * lane_w;       // distance from the lane centre
            float wheel = exp(-pow((d - 0.85) / 0.28, 2.0));
            float oil = exp(-pow(d / 0.35, 2.0));
            float streak = 0.6 + 0.8 * nz(vec2(p.x * 0.01, p.y * 0.8), 2);
            base *= 1.0 + 0.10 * wheel * streak - 0.16 * oil * streak;
        }
        spec = 0.05;
    } else if (mat == 1) {     // road.surface_texture / road.joints set: the same pattern, scaled; concrete slabs
        // (kept apart from the branch above so that the default surface renders exactly as before)
        float g = nz(p * 0.9, 0) * 0.6 + nz(p * 0.23, 0) * 0.4;
        float patch = nz(p * 0.013, 1);
        float wear = nz(vec2(p.x * 0.004, p.y * 0.35), 2);
        float m = (0.70 + 0.45 * g) * (0.80 + 0.40 * patch) * (0.90 + 0.20 * wear);
        m += 0.1 * smoothstep(0.7, 0.9, nz(p * 0.05, 3));
        float a = abs(p.y - bend(p.x)) - median_half;
        if (a > 0.0 && a < carriage_w) {
            float d = abs(fract(a / lane_w) - 0.5) * lane_w;
            float wheel = exp(-pow((d - 0.85) / 0.28, 2.0));
            float oil = exp(-pow(d / 0.35, 2.0));
            float streak = 0.6 + 0.8 * nz(vec2(p.x * 0.01, p.y * 0.8), 2);
            m *= 1.0 + 0.10 * wheel * streak - 0.16 * oil * streak;
        }
        base *= max(1.0 + surface_tex * (m - 1.0), 0.05);
        if (joints > 0.0) {
            // slabs: a slightly different tone per slab and lane, dark sealed joints between them (box-filtered
            // over the pixel's footprint along the road, so distant joints fade instead of aliasing)
            float xb = p.x / joints;
            float lane = a > 0.0 ? floor(a / lane_w) : -1.0;
            base *= 0.95 + 0.10 * nz(vec2(floor(xb) * 0.173 + lane * 0.311, 0.5 + lane * 0.137), 1);
            float jd = abs(fract(xb + 0.5) - 0.5) * joints;        // metres from the nearest joint
            float fw = max(fwidth(p.x), 1e-4);
            float cover = clamp((min(jd + 0.5 * fw, 0.012) - max(jd - 0.5 * fw, -0.012)) / fw, 0.0, 1.0);
            base *= 1.0 - 0.55 * cover;
        }
        spec = 0.05;
    } else if (mat == 2) {     // grass and fields
        float g = nz(p * 0.7, 0) * 0.5 + nz(p * 0.11, 1) * 0.5;
        base *= 0.65 + 0.6 * g;
        base = mix(base, vec3(0.42, 0.38, 0.22), 0.35 * nz(p * 0.02, 2));
    } else if (mat == 3) {     // worn paint
        base *= 0.80 + 0.25 * nz(p * 1.7, 0);
        base = mix(base, vec3(0.35), 0.35 * smoothstep(0.55, 0.9, nz(p * 0.08, 3)));
    } else if (mat == 4) {     // galvanised steel
        base *= 0.85 + 0.2 * nz(vec2(p.x + p.y, v_pos.z) * 0.5, 0);
        spec = 0.5; shin = 30.0;
    } else if (mat == 5) {     // concrete, gravel
        base *= 0.78 + 0.35 * nz(p * 1.3 + v_pos.z, 0);
    } else if (mat == 6) {     // foliage
        base *= 0.6 + 0.7 * nz(vec2(p.x + p.y, v_pos.z) * 0.6, 0);
    } else if (mat == 7) {     // lamp glass
        if (lamps_on > 0.5) emit = vec3(1.6, 1.3, 0.9);
    } else if (mat == 8) {
        spec = 0.2;
    } else
#endif
    if (mat == 10) {    // car paint
        spec = 1.2; shin = 20.0; refl = 0.60;   // clear coat: strong sky reflections (NanoDet recall rose with them)
        float plastic = 1.0 - smoothstep(0.26, 0.30, v_pos.z);  // black sills, lower bumpers, arch liners
        base = mix(base, vec3(0.05, 0.05, 0.055), plastic);
        refl *= 1.0 - plastic; spec *= 1.0 - 0.8 * plastic;
    } else if (mat == 11) {    // glass
        spec = 0.9; shin = 80.0; refl = 0.65;   // glass: mostly sky reflection
    } else if (mat == 12) {    // tyres
        spec = 0.02;
    } else if (mat == 13) {    // headlights
        spec = 0.8; shin = 60.0;
        if (lights_on > 0.5) emit = vec3(2.2, 2.1, 1.9);
    } else if (mat == 14) {    // tail lights
        spec = 0.5;
        if (lights_on > 0.5) emit = vec3(1.6, 0.08, 0.05);
    } else if (mat == 16) {
        spec = 0.1;
    }
    float ndl = max(dot(n, sun_dir), 0.0);
    vec3 h = normalize(sun_dir + view);
#ifndef VEHICLES_ONLY
    vec3 light = amb_col * (0.75 + 0.25 * n.z) + sun_col * ndl + lamp_light(v_pos, n);
    if (mat >= 10) {           // vehicles: ambient occlusion near the road and on down-facing faces
#else
    vec3 light; {
#endif
        float occ = mix(0.35, 1.0, smoothstep(0.05, 0.75, v_pos.z)) * mix(0.35, 1.0, smoothstep(-0.6, 0.1, n.z));
        light = amb_col * (0.55 + 0.45 * n.z) * occ + sun_col * ndl * mix(0.5, 1.0, occ) + lamp_light(v_pos, n);
    }
    vec3 c = base * light + sun_col * spec * pow(max(dot(n, h), 0.0), shin) * step(0.0, ndl);
    if (refl > 0.0) {
        vec3 r = reflect(-view, n);
        float fres = refl + (1.0 - refl) * pow(1.0 - max(dot(n, view), 0.0), 5.0);
        vec3 env = mix(sky_col * 0.7, zenith_col, clamp(r.z, 0.0, 1.0));
        env = r.z < 0.0 ? amb_col * 0.5 : env;
        c = mix(c, env, clamp(fres, 0.0, 1.0) * (mat == 11 ? 1.0 : 0.5));
    }
    c += emit;
    c = mix(c, 0.8 + 0.2 * (1.0 - exp(-(c - 0.8) / 0.2)), step(0.8, c));  // sensor knee: soft highlights
    float dist = length(cam_pos - v_pos);
    float fog = 1.0 - exp(-haze * dist / 500.0);
    c = mix(c, sky_col, fog);
    f_col = vec4(c, v_id / 255.0);  // alpha carries the vehicle slot (0 = scene)
}
"""

_ID_VERT = """
#version 330
uniform mat4 mvp;
in vec3 in_pos; in float in_id;
flat out float v_id;
void main() { v_id = in_id; gl_Position = mvp * vec4(in_pos, 1.0); }
"""

_ID_FRAG = """
#version 330
flat in float v_id;
layout(location = 0) out vec4 f_col;
void main() { f_col = vec4(v_id / 255.0); }  // (red of a one-channel target)
"""

_COPY_FRAG = """
#version 330
uniform sampler2D image;
layout(location = 0) out vec4 f_col;
void main() { f_col = vec4(texelFetch(image, ivec2(gl_FragCoord.xy), 0).rgb, 0.0); }
"""

_SKY_VERT = """
#version 330
in vec2 in_pos; out vec2 v_uv;
void main() { v_uv = in_pos * 0.5 + 0.5; gl_Position = vec4(in_pos, 1.0, 1.0); }
"""

_SKY_FRAG = """
#version 330
uniform mat3 ray_from_ndc; uniform vec3 sky_col; uniform vec3 zenith_col; uniform vec3 cloud_col;
uniform float clouds; uniform sampler2D noise;
in vec2 v_uv;
layout(location = 0) out vec4 f_col;
void main() {
    vec3 d = normalize(ray_from_ndc * vec3(v_uv * 2.0 - 1.0, 1.0));
    float e = clamp(d.z, 0.0, 1.0);
    vec3 c = mix(sky_col, zenith_col, pow(e, 0.6));
    if (d.z > 0.0) {
        vec2 q = d.xy / (d.z + 0.05) * 0.02;
        float k = texture(noise, q).g * 0.6 + texture(noise, q * 3.1).r * 0.4;
        c = mix(c, cloud_col, clouds * smoothstep(0.45, 0.8, k) * smoothstep(0.0, 0.15, d.z));
    }
    f_col = vec4(c, 0.0);
}
"""

_SHADOW_VERT = """
#version 330
uniform mat4 mvp;
in vec3 in_pos; in float in_alpha;
out float v_alpha;
void main() { v_alpha = in_alpha; gl_Position = mvp * vec4(in_pos, 1.0); }
"""

_SHADOW_FRAG = """
#version 330
in float v_alpha;
layout(location = 0) out vec4 f_col;
void main() { f_col = vec4(0.0, 0.0, 0.0, v_alpha); }
"""

_GLOW_VERT = """
#version 330
uniform mat4 mvp;
in vec3 in_pos; in vec2 in_uv; in vec3 in_col;
out vec2 v_uv; out vec3 v_col;
void main() { v_uv = in_uv; v_col = in_col; gl_Position = mvp * vec4(in_pos, 1.0); }
"""

_GLOW_FRAG = """
#version 330
in vec2 v_uv; in vec3 v_col;
layout(location = 0) out vec4 f_col;
void main() {
    float a = pow(max(1.0 - v_uv.x, 0.0), 2.0) * max(1.0 - v_uv.y * v_uv.y, 0.0) * smoothstep(0.0, 0.08, v_uv.x);
    f_col = vec4(v_col * a, 0.0);
}
"""

_BACKDROP_FRAG = """
#version 330
uniform sampler2D image;
in vec2 v_uv;
layout(location = 0) out vec4 f_col;
void main() { f_col = vec4(texture(image, vec2(v_uv.x, 1.0 - v_uv.y)).rgb, 0.0); }
"""


@dataclass(frozen=True)
class Light:
    """Resolved lighting for one preset."""

    sun_dir: np.ndarray  # unit vector towards the sun (world)
    sun_col: np.ndarray
    amb_col: np.ndarray
    sky_col: np.ndarray  # horizon
    zenith_col: np.ndarray
    cloud_col: np.ndarray
    clouds: float
    shadow: float  # opacity of sun shadows
    contact: float  # opacity of contact shadows under vehicles
    lights_on: bool  # vehicle head/tail lights
    lamps_on: bool
    haze: float


_BLIT_OVERHEAD = 0.03  # fixed cost of one scissored resolve, as a fraction of a whole-frame one

Rect = tuple[int, int, int, int]  # x, y, w, h (OpenGL's bottom-left origin)
_BOX_CORNERS = np.array(list(itertools.product((0, 1), repeat=3)))  # (lo, hi) choice per axis of a box's corners


def _bounding(a: Rect, b: Rect) -> Rect:
    """The smallest rectangle holding ``a`` and ``b``."""
    x0, y0 = min(a[0], b[0]), min(a[1], b[1])
    return x0, y0, max(a[0] + a[2], b[0] + b[2]) - x0, max(a[1] + a[3], b[1] + b[3]) - y0


def _grow(rect: Rect, px: int, size: tuple[int, int]) -> Rect:
    """``rect`` grown by ``px`` on every side, clipped to the frame ``size``."""
    x, y, w, h = rect
    x0, y0 = max(x - px, 0), max(y - px, 0)
    return x0, y0, min(x + w + px, size[0]) - x0, min(y + h + px, size[1]) - y0


_GL_RENDERBUFFER = 0x8D41


@functools.lru_cache(maxsize=1)
def _copy_image_sub_data():
    """OpenGL 4.3's glCopyImageSubData (which moderngl does not wrap) from EGL, or None where it is missing."""
    import ctypes
    import ctypes.util

    try:
        egl = ctypes.CDLL(ctypes.util.find_library("EGL") or "libEGL.so.1")
    except OSError:
        return None
    egl.eglGetProcAddress.restype = ctypes.c_void_p
    egl.eglGetProcAddress.argtypes = [ctypes.c_char_p]
    addr = egl.eglGetProcAddress(b"glCopyImageSubData")
    if not addr:
        return None
    image = [ctypes.c_uint, ctypes.c_uint, ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_int]
    return ctypes.CFUNCTYPE(None, *image, *image, ctypes.c_int, ctypes.c_int, ctypes.c_int)(addr)


def _clip_near(clip: np.ndarray) -> np.ndarray:
    """Clip-space points (N, 4) whose convex hull is that of ``clip`` cut by OpenGL's near plane (z >= -w):
    the points in front of it and the crossings of every segment from a point in front to one behind."""
    d = clip[:, 2] + clip[:, 3]
    front, back = d >= 0, d < 0
    if not back.any():
        return clip
    t = d[front][:, None] / (d[front][:, None] - d[back][None, :])  # (front, back) segment fractions
    a, b = clip[front][:, None, :], clip[back][None, :, :]
    return np.concatenate([clip[front], (a + t[..., None] * (b - a)).reshape(-1, 4)])


@functools.lru_cache(maxsize=1024)
def _contact_shadow(hl: float, hw: float, opacity: float) -> tuple[np.ndarray, np.ndarray]:
    """Triangles (vehicle frame, metres) and opacities of the soft contact shadow under a vehicle of half length
    ``hl`` and half width ``hw``: an opaque inner rectangle and a ring fading to transparent outside it."""
    inner = np.array([[hl - 0.2, hw - 0.2], [-hl + 0.2, hw - 0.2], [-hl + 0.2, -hw + 0.2], [hl - 0.2, -hw + 0.2]])
    outer = np.array([[hl + 0.5, hw + 0.45], [-hl - 0.5, hw + 0.45], [-hl - 0.5, -hw - 0.45], [hl + 0.5, -hw - 0.45]])
    tri = [(inner[0], opacity), (inner[1], opacity), (inner[2], opacity),
           (inner[0], opacity), (inner[2], opacity), (inner[3], opacity)]
    for i in range(4):
        j = (i + 1) % 4
        tri += [(inner[i], opacity), (outer[i], 0.0), (outer[j], 0.0),
                (inner[i], opacity), (outer[j], 0.0), (inner[j], opacity)]
    local = np.array([p for p, _ in tri])
    alpha = np.array([a for _, a in tri])
    local.flags.writeable = alpha.flags.writeable = False  # shared by every call (cached)
    return local, alpha


def _merge_rects(rects: list[Rect]) -> list[Rect]:
    """Rectangles that overlap so much that their bounding box is no larger than their two areas together (a
    vehicle's rectangles in consecutive frames) merged into that box, so no pixel is resolved twice over."""
    out = list(rects)
    merged = True
    while merged:
        merged = False
        for i in range(len(out)):
            for j in range(i + 1, len(out)):
                box = _bounding(out[i], out[j])
                if box[2] * box[3] <= out[i][2] * out[i][3] + out[j][2] * out[j][3]:
                    out[i] = box
                    del out[j]
                    merged = True
                    break
            if merged:
                break
    return out


def _material_only(frag: str, mat: int) -> str:
    """The scene's fragment shader for fragments of material ``mat`` only (a constant, so the other materials'
    branches, which llvmpipe would run masked for every fragment, are compiled out; same code for ``mat``)."""
    return frag.replace("#version 330\n", f"#version 330\n#define ONLY_MAT {int(mat)}\n", 1)


def _material_runs(mats: np.ndarray) -> list[tuple[int, int, int]]:
    """(first vertex, vertex count, material) of each run of equal materials in ``mats`` (one per vertex)."""
    m = np.rint(np.asarray(mats)).astype(int)
    if len(m) == 0:
        return []
    starts = np.flatnonzero(np.r_[True, m[1:] != m[:-1]])
    ends = np.r_[starts[1:], len(m)]
    return [(int(a), int(b - a), int(m[a])) for a, b in zip(starts, ends)]


_SCENE_ATTRIBUTES = (("3f", "in_pos"), ("3f", "in_normal"), ("3f", "in_col"), ("1f", "in_mat"), ("1f", "in_id"))


def _attributes(prog, layout: tuple[tuple[str, str], ...]) -> tuple[str, ...]:
    """moderngl vertex-array content (format, names...) for ``layout``, attributes ``prog`` does not use skipped."""
    fmt, names = [], []
    for f, name in layout:
        if name in prog:
            fmt.append(f)
            names.append(name)
        else:
            fmt.append(f"{4 * int(f[:-1])}x")
    return (" ".join(fmt), *names)


def _vehicles_only(frag: str) -> str:
    """The scene's fragment shader for vehicle fragments only: the static materials' branches are left out
    (llvmpipe evaluates every branch of a fragment's material chain, masked, so they cost the vehicles more
    than their own shading); the vehicle materials' code is the same, so their pixels are too."""
    return frag.replace("#version 330\n", "#version 330\n#define VEHICLES_ONLY\n", 1)


def resolve_lighting(spec: LightingSpec) -> Light:
    """Colours and strengths for the lighting preset (then the scenario's sun angles)."""
    elev = spec.sun_elevation
    c = lambda *v: np.array(v, np.float32)  # noqa: E731
    if spec.preset == "day":
        p = dict(sun_col=c(1.0, 0.95, 0.86) * 0.95, amb_col=c(0.50, 0.55, 0.64) * 0.75, sky_col=c(0.78, 0.84, 0.92),
                 zenith_col=c(0.33, 0.52, 0.85), cloud_col=c(0.95, 0.95, 0.97), clouds=0.6, shadow=0.55,
                 contact=0.75, lights_on=False, lamps_on=False)
    elif spec.preset == "overcast":
        p = dict(sun_col=c(0.9, 0.9, 0.92) * 0.18, amb_col=c(0.80, 0.81, 0.84) * 0.95, sky_col=c(0.80, 0.81, 0.83),
                 zenith_col=c(0.62, 0.64, 0.68), cloud_col=c(0.70, 0.71, 0.73), clouds=0.8, shadow=0.12,
                 contact=0.7, lights_on=False, lamps_on=False)
    elif spec.preset == "dusk":
        elev = min(elev, 8.0)
        p = dict(sun_col=c(1.0, 0.62, 0.38) * 0.55, amb_col=c(0.40, 0.38, 0.50) * 0.55, sky_col=c(0.92, 0.60, 0.42),
                 zenith_col=c(0.22, 0.27, 0.48), cloud_col=c(0.85, 0.50, 0.45), clouds=0.5, shadow=0.35,
                 contact=0.7, lights_on=True, lamps_on=True)
    else:  # night
        p = dict(sun_col=c(0, 0, 0), amb_col=c(0.06, 0.07, 0.10), sky_col=c(0.05, 0.06, 0.10),
                 zenith_col=c(0.01, 0.015, 0.03), cloud_col=c(0.08, 0.08, 0.10), clouds=0.3, shadow=0.0,
                 contact=0.5, lights_on=True, lamps_on=True)
    if spec.lamps is not None:
        p["lamps_on"] = bool(spec.lamps)
    az, el = np.radians(spec.sun_azimuth), np.radians(elev)
    sun = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], np.float32)
    return Light(sun_dir=sun, haze=spec.haze, **p)


# ------------------------------------------------------------------------------- vehicle meshes

_PART_STYLE = {  # part name in vehicles.mesh -> (material, fixed colour or None for body colour)
    "PART_BODY": (MAT_BODY, None), "PART_WINDOW": (MAT_GLASS, (0.06, 0.08, 0.10)),
    "PART_WHEEL": (MAT_RUBBER, (0.05, 0.05, 0.05)), "PART_HEADLIGHT": (MAT_HEADLIGHT, (0.80, 0.80, 0.78)),
    "PART_TAILLIGHT": (MAT_TAILLIGHT, (0.55, 0.04, 0.04)), "PART_PLATE": (MAT_PLATE, (0.90, 0.90, 0.86)),
    "PART_TRIM": (MAT_TRIM, (0.10, 0.10, 0.11)),
}


def _part_table() -> dict[int, tuple[int, tuple | None]]:
    try:
        from ..vehicles import mesh as vm
    except ImportError:
        return {0: (MAT_BODY, None)}
    table = {}
    for name, style in _PART_STYLE.items():
        if hasattr(vm, name):
            table[int(getattr(vm, name))] = style
    return table


@dataclass
class BoxMesh:
    """A cuboid vehicle (vehicle frame: x forward, origin at the bottom-face centre).  Exactness tests use it
    because its silhouette is exactly the projected 3D bounding box."""

    vertices: np.ndarray
    faces: np.ndarray
    parts: np.ndarray
    body_colour: tuple[float, float, float]

    @classmethod
    def make(cls, length: float, width: float, height: float, colour=(0.6, 0.1, 0.1)) -> "BoxMesh":
        L, W = length / 2, width / 2
        v = np.array([[x, y, z] for z in (0, height) for y in (-W, W) for x in (-L, L)], np.float32)
        quads = [(0, 1, 5, 4), (1, 3, 7, 5), (3, 2, 6, 7), (2, 0, 4, 6), (4, 5, 7, 6), (0, 2, 3, 1)]
        f = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))], np.uint32)
        return cls(v, f, np.zeros(len(f), np.uint8), tuple(colour))


def proxy_mesh(v, mesh) -> BoxMesh:
    """A low-detail stand-in for a distant vehicle (a few boxes: dark wheel zone, body, glass cabin) with the same
    bounding box and body colour as its full mesh."""
    try:
        from ..vehicles.parts import PART_BODY, PART_WHEEL, PART_WINDOW
    except ImportError:
        PART_BODY, PART_WHEEL, PART_WINDOW = 0, 0, 0
    L, W, H = v.length, v.width, v.height
    tall = v.body_style in ("van", "bus", "truck") or H > 2.3
    boxes = [(-0.46 * L, 0.46 * L, 0.96 * W, 0.0, 0.3 * H, PART_WHEEL)]
    if v.body_style == "motorcycle":
        boxes = [(-0.5 * L, 0.5 * L, W, 0.0, 0.35 * H, PART_WHEEL), (-0.25 * L, 0.3 * L, W, 0.35 * H, H, PART_BODY)]
    elif tall:
        boxes += [(-0.5 * L, 0.5 * L, W, 0.3 * H, H, PART_BODY)]
    else:
        boxes += [(-0.5 * L, 0.5 * L, W, 0.3 * H, 0.62 * H, PART_BODY),
                  (-0.32 * L, 0.22 * L, 0.86 * W, 0.62 * H, H, PART_WINDOW)]
    Vs, Fs, Ps = [], [], []
    for x0, x1, w, z0, z1, part in boxes:
        b = BoxMesh.make(x1 - x0, w, z1 - z0)
        Fs.append(b.faces + sum(len(a) for a in Vs))
        Vs.append(b.vertices + np.array([(x0 + x1) / 2, 0.0, z0], np.float32))
        Ps.append(np.full(len(b.faces), part, np.uint8))
    return BoxMesh(np.concatenate(Vs), np.concatenate(Fs), np.concatenate(Ps), tuple(mesh.body_colour))


def simplified_mesh(mesh, cell: float) -> BoxMesh:
    """Vertex clustering: vertices snapped to a grid of ``cell`` metres are merged (at their mean), faces that
    collapse are dropped.  A mid-distance level of detail that keeps parts, colours and the overall shape."""
    V = np.asarray(mesh.vertices, np.float64)
    F = np.asarray(mesh.faces, np.int64)
    _, inv, cnt = np.unique(np.floor(V / cell).astype(np.int64), axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    merged = np.zeros((len(cnt), 3))
    np.add.at(merged, inv, V)
    merged /= cnt[:, None]
    F2 = inv[F]
    keep = (F2[:, 0] != F2[:, 1]) & (F2[:, 1] != F2[:, 2]) & (F2[:, 0] != F2[:, 2])
    F2, P = F2[keep], np.asarray(mesh.parts)[keep]
    _, first = np.unique(np.sort(F2, axis=1), axis=0, return_index=True)
    first = np.sort(first)
    return BoxMesh(merged.astype(np.float32), F2[first].astype(np.uint32), P[first].astype(np.uint8),
                   tuple(mesh.body_colour))


def mesh_vertices(mesh, direction: int, part_table: dict) -> np.ndarray:
    """Flat-shaded vertex rows (pos, normal, colour, material, id=0) of a vehicle mesh turned to its direction."""
    V = np.asarray(mesh.vertices, np.float32)
    if direction == 1:
        V = V * np.array([-1, -1, 1], np.float32)
    F = np.asarray(mesh.faces, np.int64)
    P = V[F]  # (M, 3, 3)
    n = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    parts = np.asarray(mesh.parts, np.int64)
    mat = np.full(len(F), MAT_BODY, np.float32)
    col = np.tile(np.asarray(mesh.body_colour, np.float32), (len(F), 1))
    for pid, (m, c) in part_table.items():
        sel = parts == pid
        mat[sel] = m
        if c is not None:
            col[sel] = c
    rows = np.empty((len(F), 3, 11), np.float32)
    rows[..., 0:3] = P
    rows[..., 3:6] = n[:, None]
    rows[..., 6:9] = col[:, None]
    rows[..., 9] = mat[:, None]
    rows[..., 10] = 0
    return rows.reshape(-1, 11)


# ------------------------------------------------------------------------------- renderer


def _noise_texture(rng: np.random.Generator, size: int = 512) -> np.ndarray:
    """Tileable RGBA noise: fractal value noise at several scales (channels differ in character)."""
    import cv2

    def fractal(octaves, persistence):
        acc = np.zeros((size, size), np.float32)
        amp, total = 1.0, 0.0
        for o in octaves:
            g = rng.random((o, o)).astype(np.float32)
            g = np.tile(g, (3, 3))
            up = cv2.resize(g, (3 * size, 3 * size), interpolation=cv2.INTER_CUBIC)[size:2 * size, size:2 * size]
            acc += amp * up
            total += amp
            amp *= persistence
        acc /= total
        acc = (acc - acc.min()) / max(float(np.ptp(acc)), 1e-6)
        return acc

    r = fractal([512, 256, 128, 64], 0.8)  # fine grain
    g = fractal([8, 16, 32, 64], 0.6)  # patches
    b = fractal([4, 8, 16, 128], 0.5)
    a = fractal([16, 32, 64, 256], 0.7)
    return (np.stack([r, g, b, a], -1) * 255).astype(np.uint8)


class Renderer:
    """Draws frames of one scene; construct once, call :meth:`render` per frame."""

    def __init__(self, cam: SynthCamera, light: Light, ground: np.ndarray, objects: np.ndarray,
                 lamps: list[tuple[float, float]], lamp_spacing: float, backdrop: np.ndarray | None = None,
                 seed: int = 0, road: tuple[float, ...] = (3.5, 0.0, 0.0), surface_texture: float = 1.0,
                 joints: float = 0.0):
        import moderngl

        self.cam, self.light = cam, light
        W, H = cam.size
        self.size = (W, H)
        self.ctx = ctx = moderngl.create_standalone_context(backend="egl")
        rng = np.random.default_rng(seed)
        self.noise = ctx.texture((512, 512), 4, _noise_texture(rng).tobytes())
        self.noise.build_mipmaps()
        self.noise.repeat_x = self.noise.repeat_y = True
        self.noise.anisotropy = 1.0
        # the static scene is drawn run by run with one program per material, the vehicles with a program
        # for vehicle materials only (the same shader code each)
        self.mat_progs = {m: ctx.program(vertex_shader=_VERT, fragment_shader=_material_only(_FRAG, m))
                          for m in sorted({r[2] for a in (ground, objects) for r in _material_runs(a[:, 9])})}
        self.veh_prog = ctx.program(vertex_shader=_VERT, fragment_shader=_vehicles_only(_FRAG))
        self.sky = ctx.program(vertex_shader=_SKY_VERT, fragment_shader=_SKY_FRAG)
        self.shadow = ctx.program(vertex_shader=_SHADOW_VERT, fragment_shader=_SHADOW_FRAG)
        self.glow = ctx.program(vertex_shader=_GLOW_VERT, fragment_shader=_GLOW_FRAG)
        self.id_prog = ctx.program(vertex_shader=_ID_VERT, fragment_shader=_ID_FRAG)
        self.quad = ctx.buffer(np.array([-1, -1, 1, -1, -1, 1, 1, 1], np.float32).tobytes())
        mvp = cam.gl_matrix().astype(np.float32)
        self.mvp = mvp
        self._mvp_t = mvp.T.astype(np.float64)  # clip = [world, 1] @ _mvp_t
        for p in (*self.mat_progs.values(), self.veh_prog, self.shadow, self.glow, self.id_prog):
            p["mvp"].write(mvp.T.tobytes())
        self._set_uniforms(lamps, lamp_spacing)
        self.set_road(*road, surface_texture=surface_texture, joints=joints)
        # targets: cached static scene (colour + depth, single- and multisampled), the multisampled frame where
        # everything is drawn, the frame (its resolved colour) and the vehicle-id target (ids + depth at pixel
        # centres; its source is the static depth with zero ids)
        self.bg_tex = ctx.texture((W, H), 4)
        bg_depth = ctx.depth_renderbuffer((W, H))
        self.bg_fbo = ctx.framebuffer([self.bg_tex], bg_depth)
        self.samples = min(4, ctx.max_samples)
        self.ms_fbo = ctx.framebuffer([ctx.renderbuffer((W, H), 4, samples=self.samples)],
                                      ctx.depth_renderbuffer((W, H), samples=self.samples))
        self.ms_static = ctx.framebuffer([ctx.renderbuffer((W, H), 4, samples=self.samples)],
                                         ctx.depth_renderbuffer((W, H), samples=self.samples))
        self.fbo = ctx.framebuffer([ctx.renderbuffer((W, H), 4)])
        self.id_fbo = ctx.framebuffer([ctx.renderbuffer((W, H), 1)], ctx.depth_renderbuffer((W, H)))
        self._id_src = ctx.framebuffer([ctx.renderbuffer((W, H), 1)], bg_depth)
        self._id_src.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        self._ids = np.empty((H, W), np.uint8)
        self._frame = np.empty((H, W, 3), np.uint8)
        self._dirty: list[tuple[int, int, int, int] | None] = [(0, 0, W, H)]  # first frame: everything
        self._copy_image = _copy_image_sub_data()
        self.part_table = _part_table()
        self._veh_cache: dict[int, np.ndarray] = {}
        self._pts_cache: dict[int, np.ndarray] = {}
        self._tri_cache: dict = {}
        self.frame_triangles: list[np.ndarray] = []  # per drawn vehicle: faces as indices into frame_points
        self.frame_points: list[np.ndarray] = []  # per drawn vehicle: its mesh's vertices in the world (metres)
        self._veh_buf = ctx.buffer(reserve=4 * 11 * 3 * 20000, dynamic=True)
        self._shadow_buf = ctx.buffer(reserve=4 * 4 * 3 * 20000, dynamic=True)
        self._glow_buf = ctx.buffer(reserve=4 * 8 * 600, dynamic=True)
        self._render_static(ground, objects, backdrop)

    def set_road(self, lane_width: float, median_half: float, carriageway_width: float, curve_start: float = 0.0,
                 curve_radius: float = 0.0, surface_texture: float = 1.0, joints: float = 0.0) -> None:
        """Lane geometry for the wheel-path and oil-strip pattern of the asphalt and the lamp rows, the road
        surface's texture contrast and slab joints (``RoadSpec.surface_texture``, ``joints``; before the static
        pass)."""
        self._set_scene_uniforms(dict(curve_start=float(curve_start),
                                      curve_inv_r=1.0 / curve_radius if curve_radius else 0.0,
                                      lane_w=float(lane_width), median_half=float(median_half),
                                      carriage_w=float(carriageway_width), surface_tex=float(surface_texture),
                                      joints=float(joints)))

    def _set_scene_uniforms(self, values: dict) -> None:
        """Set uniforms of the scene programs (per material and for vehicles; each where it uses them)."""
        for prog in (*self.mat_progs.values(), self.veh_prog):
            for k, v in values.items():
                if k in prog:
                    prog[k].value = tuple(np.asarray(v).tolist()) if np.ndim(v) else v

    def _set_uniforms(self, lamps, lamp_spacing) -> None:
        L, cam = self.light, self.cam
        vals = dict(sun_dir=L.sun_dir, sun_col=L.sun_col, amb_col=L.amb_col, sky_col=L.sky_col,
                    zenith_col=L.zenith_col, cam_pos=cam.centre.astype(np.float32), haze=L.haze,
                    lamps_on=float(L.lamps_on), lights_on=float(L.lights_on), lamp_spacing=float(lamp_spacing),
                    lamp_x0=float(lamps[0][0]) if lamps else 0.0, lamp_y=float(abs(lamps[0][1])) if lamps else 0.0)
        self._set_scene_uniforms(vals)
        for k in ("sky_col", "zenith_col", "cloud_col", "clouds"):
            if k in self.sky:
                v = getattr(L, k)
                self.sky[k].value = tuple(np.asarray(v).tolist()) if np.ndim(v) else float(v)
        K, R = cam.K, cam.R
        W, H = cam.size
        # ndc -> pixel -> ray (world)
        to_px = np.array([[W / 2, 0, W / 2 - 0.5], [0, -H / 2, H / 2 - 0.5], [0, 0, 1]])
        m = R.T @ np.linalg.inv(K) @ to_px
        self.sky["ray_from_ndc"].write(m.T.astype(np.float32).tobytes())

    def _render_static(self, ground: np.ndarray, objects: np.ndarray, backdrop: np.ndarray | None) -> None:
        import moderngl

        ctx = self.ctx
        self.bg_fbo.use()
        self.bg_fbo.clear(0, 0, 0, 1, depth=1.0)
        self.noise.use(0)
        if backdrop is not None:
            img = np.ascontiguousarray(backdrop[:, :, :3])
            tex = ctx.texture((img.shape[1], img.shape[0]), 3, img.tobytes())
            tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
            prog = ctx.program(vertex_shader=_SKY_VERT, fragment_shader=_BACKDROP_FRAG)
            tex.use(3)
            prog["image"].value = 3
            ctx.disable(moderngl.DEPTH_TEST)
            ctx.vertex_array(prog, [(self.quad, "2f", "in_pos")]).render(moderngl.TRIANGLE_STRIP)
            self._fill_ms_static(None)
            return
        bufs, runs = [], []
        for arr in (ground, objects):
            rows = np.concatenate([arr, np.zeros((len(arr), 1), np.float32)], 1)
            bufs.append(ctx.buffer(rows.astype(np.float32).tobytes()) if len(rows) else None)
            runs.append(_material_runs(arr[:, 9]))

        def draw(shaded: bool = True) -> None:
            """The static scene; unshaded: only its depth (the raised objects through the trivial id shader, the
            same positions; the sky and ground layers are drawn without the depth test, so they write none)."""
            if not shaded:
                if bufs[1] is not None:
                    ctx.enable(moderngl.DEPTH_TEST)
                    vao = ctx.vertex_array(self.id_prog, [(bufs[1], "3f 28x 1f", "in_pos", "in_id")])
                    vao.render(moderngl.TRIANGLES)
                    vao.release()
                return
            ctx.disable(moderngl.DEPTH_TEST)
            ctx.vertex_array(self.sky, [(self.quad, "2f", "in_pos")]).render(moderngl.TRIANGLE_STRIP)
            # ground layers in paint order without depth (coplanar), then raised objects with depth
            for buf, buf_runs, depth in zip(bufs, runs, (False, True)):
                if buf is None:
                    continue
                if depth:
                    ctx.enable(moderngl.DEPTH_TEST)
                else:
                    ctx.disable(moderngl.DEPTH_TEST)
                for first, count, mat in buf_runs:  # in the rows' order (paint order, depth ties)
                    prog = self.mat_progs[mat]
                    vao = ctx.vertex_array(prog, [(buf, *_attributes(prog, _SCENE_ATTRIBUTES))])
                    vao.render(moderngl.TRIANGLES, vertices=count, first=first)
                    vao.release()

        draw(shaded=False)  # depth at the frame size (its colour is replaced below)
        # colour supersampled 2x2 and averaged: thin distant markings and rails do not shimmer (rendered once)
        import cv2
        W, H = self.size
        ss = ctx.framebuffer([ctx.renderbuffer((2 * W, 2 * H), 4)], ctx.depth_renderbuffer((2 * W, 2 * H)))
        ss.use()
        ss.clear(0, 0, 0, 0, depth=1.0)
        draw()
        big = np.frombuffer(ss.read(components=4), np.uint8).reshape(2 * H, 2 * W, 4)
        self.bg_tex.write(cv2.resize(big, (W, H), interpolation=cv2.INTER_AREA).tobytes())
        ss.release()
        self._fill_ms_static(lambda: draw(shaded=False))
        for buf in bufs:
            if buf is not None:
                buf.release()
        ctx.finish()

    def _fill_ms_static(self, draw) -> None:
        """The multisampled cache of the static scene: depth per sample from the geometry (so static occluders
        cut vehicles with anti-aliased edges), colour the supersampled ``bg_tex`` replicated into every sample
        (the background of the frame stays exactly what it was)."""
        import moderngl

        ctx = self.ctx
        self.ms_static.use()
        self.ms_static.clear(0, 0, 0, 0, depth=1.0)
        if draw is not None:
            draw()
        ctx.disable(moderngl.DEPTH_TEST)
        self.ms_static.depth_mask = False
        self.ms_static.use()  # (moderngl applies the masks on use)
        prog = ctx.program(vertex_shader=_SKY_VERT, fragment_shader=_COPY_FRAG)
        self.bg_tex.use(3)
        prog["image"].value = 3
        vao = ctx.vertex_array(prog, [(self.quad, "2f", "in_pos")])
        vao.render(moderngl.TRIANGLE_STRIP)
        vao.release()
        prog.release()
        self.ms_static.depth_mask = True

    # ---------------------------------------------------------------- per frame
    def vehicle_rows(self, v, mesh) -> np.ndarray:
        """Cached flat-shaded vertex rows of a vehicle's mesh (full or proxy), turned to its direction of travel."""
        key = (v.id, id(mesh))
        rows = self._veh_cache.get(key)
        if rows is None:
            rows = mesh_vertices(mesh, v.direction, self.part_table)
            self._veh_cache[key] = rows
            V, inverse = np.unique(np.asarray(mesh.vertices, np.float64), axis=0, return_inverse=True)
            self._pts_cache[key] = V * [-1, -1, 1] if v.direction == 1 else V
            self._tri_cache[key] = inverse.reshape(-1)[np.asarray(mesh.faces, np.int64)]
        return rows

    def forget(self, keep_ids: set[int]) -> None:
        for k in [k for k in self._veh_cache if k[0] not in keep_ids]:
            del self._veh_cache[k]
            del self._pts_cache[k]
            del self._tri_cache[k]

    def render(self, items: list[tuple]) -> tuple[np.ndarray, np.ndarray]:
        """Draw vehicles ``(vehicle, mesh, world offset (3,)[, extra yaw])``; return the frame, top row first: RGB
        uint8 (H, W, 3) and the vehicle slot of each pixel (H, W) uint8: 0 = no vehicle, k = items[k - 1] (so at
        most 255 vehicles per frame can be told apart)."""
        import cv2

        parts, shadows, glows, rects = [], [], [], []
        self.frame_points, self.frame_triangles = [], []
        for k, item in enumerate(items):
            rows, shadow, glow, rect = self._vehicle_geometry(k + 1, *item)
            parts.append(rows)
            shadows.append(shadow)
            glows += [glow] if glow is not None else []
            rects.append(rect)
        # the static scene (colour and depth, per sample; zero ids) is restored where the previous frame drew,
        # and only the pixels the vehicles touch now or touched then are resolved
        drawn = [_grow(r, 2, self.size) for r in self._dirty if r is not None]
        dirty = [r for r in self._dirty + rects if r is not None]
        self._dirty = rects
        self._restore(self.ms_fbo, self.ms_static, drawn)
        self._restore(self.id_fbo, self._id_src, drawn)
        if items:
            self.ms_fbo.use()
            self._draw_ground_layers(np.concatenate(shadows), np.concatenate(glows) if glows else None)
            self._veh_buf = self._upload(self._veh_buf, np.concatenate(parts))
            self._draw_vehicles(sum(len(r) for r in parts))
        self._resolve(self.fbo, self.ms_fbo, dirty)  # samples averaged (anti-aliased colour)
        self.fbo.read_into(self._frame, components=3)
        self.id_fbo.read_into(self._ids, components=1)
        return cv2.flip(self._frame, 0), cv2.flip(self._ids, 0)

    def _vehicle_geometry(self, slot: int, v, mesh, off: np.ndarray, *turn) -> tuple:
        """One vehicle's vertex rows (id = ``slot``), shadow rows, beam rows (None without lights) and screen
        rectangle; its world vertices and triangles are appended to ``frame_points`` / ``frame_triangles``."""
        key = (v.id, id(mesh))
        rows = self.vehicle_rows(v, mesh).copy()
        pts = self._pts_cache[key].copy()
        self.frame_triangles.append(self._tri_cache[key])
        yaw = turn[0] if turn else 0.0
        if yaw:  # extra yaw on a bend: rotate positions and normals about z
            c, s_ = np.cos(yaw), np.sin(yaw)
            rot = np.array([[c, s_], [-s_, c]], np.float32)
            rows[:, 0:2] = rows[:, 0:2] @ rot
            rows[:, 3:5] = rows[:, 3:5] @ rot
            pts[:, 0:2] = pts[:, 0:2] @ rot
        rows[:, 0:3] += off
        rows[:, 10] = slot
        pts += off
        self.frame_points.append(pts)
        shadow = self._shadow_rows(v, pts, off, yaw)
        glow = None
        if self.light.lights_on:
            glow = self._glow_rows(v, off)
            if yaw:
                c, s_ = np.cos(yaw), np.sin(yaw)
                glow[:, 0:2] = (glow[:, 0:2] - off[:2]) @ np.array([[c, s_], [-s_, c]], np.float32) + off[:2]
        lohi = np.stack([pts.min(0), pts.max(0)])
        box = lohi[_BOX_CORNERS, [0, 1, 2]]  # the 8 corners of the vehicle's axis-aligned box
        rect = self._screen_rect(np.concatenate([box, shadow[:, :3]] + ([glow[:, :3]] if glow is not None else [])))
        return rows, shadow, glow, rect

    def _draw_ground_layers(self, shadows: np.ndarray, glows: np.ndarray | None) -> None:
        """Shadows, then headlight beams, blended into the colour (no depth writes, destination alpha kept); the
        vehicles are drawn over them, so shadows never darken a body."""
        import moderngl

        ctx, fbo = self.ctx, self.ms_fbo
        ctx.enable(moderngl.DEPTH_TEST)
        self.noise.use(0)
        fbo.depth_mask = False
        ctx.enable(moderngl.BLEND)
        if len(shadows):
            self._shadow_buf = self._upload(self._shadow_buf, shadows)
            ctx.blend_func = moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA, moderngl.ZERO, moderngl.ONE
            self._draw(self.shadow, self._shadow_buf, "3f 1f", ("in_pos", "in_alpha"), len(shadows))
        if glows is not None:
            self._glow_buf = self._upload(self._glow_buf, glows)
            ctx.blend_func = moderngl.ONE, moderngl.ONE, moderngl.ZERO, moderngl.ONE
            self._draw(self.glow, self._glow_buf, "3f 2f 3f", ("in_pos", "in_uv", "in_col"), len(glows))
        ctx.disable(moderngl.BLEND)
        fbo.depth_mask = True

    def _draw_vehicles(self, n: int) -> None:
        """The ``n`` vertices of ``_veh_buf``: shaded into the multisampled frame, and their ids single-sampled
        with a trivial shader over the static depth (exact: never averaged; shadows and beams never enter it)."""
        self.ctx.depth_func = "<"
        self._draw(self.veh_prog, self._veh_buf, "3f 3f 3f 1f 1f",
                   ("in_pos", "in_normal", "in_col", "in_mat", "in_id"), n)
        self.id_fbo.use()  # (binding it hands the multisampled draws to llvmpipe's threads)
        self._draw(self.id_prog, self._veh_buf, "3f 28x 1f", ("in_pos", "in_id"), n)

    def _draw(self, prog, buf, fmt: str, names: tuple[str, ...], n: int) -> None:
        """Draw the first ``n`` vertices of ``buf`` as triangles with ``prog``."""
        import moderngl

        vao = self.ctx.vertex_array(prog, [(buf, fmt, *names)])
        vao.render(moderngl.TRIANGLES, vertices=n)
        vao.release()

    def _screen_rect(self, pts: np.ndarray) -> Rect | None:
        """Pixel rectangle (x, y, w, h; OpenGL's bottom-left origin) holding the projections of what OpenGL
        draws of the convex hull of ``pts`` (cut at the near plane) with a one-pixel margin; None if it is off
        the frame."""
        W, H = self.size
        clip = _clip_near(np.c_[pts, np.ones(len(pts))] @ self._mvp_t)
        if len(clip) == 0:
            return None
        xy = clip[:, :2] / clip[:, 3:4]
        x0, y0 = np.floor((xy.min(0) + 1) * 0.5 * (W, H)) - 1
        x1, y1 = np.ceil((xy.max(0) + 1) * 0.5 * (W, H)) + 1
        x0, y0, x1, y1 = max(int(x0), 0), max(int(y0), 0), min(int(x1), W), min(int(y1), H)
        return (x0, y0, x1 - x0, y1 - y0) if x1 > x0 and y1 > y0 else None

    def _whole_frame(self, rects: list[Rect]) -> bool:
        """Whether copying or resolving ``rects`` one by one costs more than one whole-frame operation."""
        W, H = self.size
        return len(rects) * _BLIT_OVERHEAD + sum(w * h for _, _, w, h in rects) / (W * H) > 0.7

    def _restore(self, dst, src, rects: list[Rect]) -> None:
        """Copy every attachment of ``src`` into ``dst`` inside ``rects``: glCopyImageSubData, a plain memory copy
        of the rectangle's samples on llvmpipe; a whole-frame copy_framebuffer (also a memory copy: 0.5 ms at
        960x540, 3.9 ms at 1080p) when that is cheaper or the function is missing.  (Scissored blits are
        shader passes: ~4 ms for 30 % of a 960x540 frame.)"""
        copy = self._copy_image if not self._whole_frame(rects) else None
        if copy is not None:
            pairs = list(zip(src.color_attachments, dst.color_attachments)) + [(src.depth_attachment,
                                                                                 dst.depth_attachment)]
            for a, b in pairs:
                for x, y, w, h in rects:
                    copy(a.glo, _GL_RENDERBUFFER, 0, x, y, 0, b.glo, _GL_RENDERBUFFER, 0, x, y, 0, w, h, 1)
            if self.ctx.error == "GL_NO_ERROR":
                return
            self._copy_image = None  # refused by this driver: whole-frame copies from now on
        self.ctx.copy_framebuffer(dst, src)

    def _resolve(self, dst, src, rects: list[Rect]) -> None:
        """Resolve the multisampled ``src`` into ``dst`` inside ``rects`` only (the blit obeys the scissor test;
        overlapping rectangles merged first).  Each blit has a fixed cost of about 3 % of a whole-frame resolve
        on llvmpipe (measured: 0.1 ms for a small rectangle, 5 ms for 960x540), so many rectangles are resolved
        as one whole frame."""
        rects = _merge_rects(rects)
        if self._whole_frame(rects):
            rects = [(0, 0, *self.size)]
        for r in rects:
            dst.scissor = r
            dst.use()
            self.ctx.copy_framebuffer(dst, src)
        dst.scissor = None
        dst.use()

    def _upload(self, buf, rows: np.ndarray):
        data = rows.astype(np.float32, copy=False).tobytes()
        if len(data) > buf.size:
            buf.release()
            buf = self.ctx.buffer(reserve=len(data) * 2, dynamic=True)
        buf.write(data)
        return buf

    def _shadow_rows(self, v, rows: np.ndarray, off: np.ndarray, turn: float = 0.0) -> np.ndarray:
        """Sun-shadow triangles (convex hull of the body's vertices projected along the light onto the road) and a
        soft contact shadow (two nested rectangles, opaque inside, transparent outside)."""
        L = self.light
        out = []
        if L.shadow > 0 and L.sun_dir[2] > 0.03:
            import cv2
            P = rows[:, :3]
            d = L.sun_dir
            proj = (P[:, :2] - d[:2] * (P[:, 2:3] / d[2])).astype(np.float32)
            hull = cv2.convexHull(proj)[:, 0]  # the vehicle's shadow is (nearly) convex: no overlaps
            n = len(hull)
            fan = np.stack([np.zeros(n - 2, int), np.arange(1, n - 1), np.arange(2, n)], 1).ravel()
            sh = np.empty((len(fan), 4), np.float32)
            sh[:, :2] = hull[fan]
            sh[:, 2] = 0.006
            sh[:, 3] = L.shadow
            out.append(sh)
        if L.contact > 0:
            local, alpha = _contact_shadow(v.length / 2, v.width / 2, L.contact)
            c, s_ = np.cos(turn), np.sin(turn)
            arr = np.empty((len(local), 4), np.float32)
            arr[:, :2] = local @ np.array([[c, s_], [-s_, c]]) + off[:2]
            arr[:, 2] = 0.004
            arr[:, 3] = alpha
            out.append(arr)
        return np.concatenate(out) if out else np.zeros((0, 4), np.float32)

    def _glow_rows(self, v, off: np.ndarray) -> np.ndarray:
        """Headlight beam on the road ahead and a faint red glow behind (additive quads with (u, v) coords)."""
        s = v.sign
        hl, hw = v.length / 2, v.width / 2
        rows = []
        for (x0, x1, w0, w1, col) in ((hl, hl + 28.0, hw, 5.0, (0.55, 0.52, 0.45)),
                                      (-hl, -hl - 4.0, hw, hw + 0.8, (0.25, 0.0, 0.0))):
            a = (off[0] + s * x0, off[1] - w0, 0.003)
            b = (off[0] + s * x1, off[1] - w1, 0.003)
            c = (off[0] + s * x1, off[1] + w1, 0.003)
            d = (off[0] + s * x0, off[1] + w0, 0.003)
            m = (off[0] + s * x0, off[1], 0.003)
            e = (off[0] + s * x1, off[1], 0.003)
            for P, uv in (((m, a, b), ((0, 0), (0, 1), (1, 1))), ((m, b, e), ((0, 0), (1, 1), (1, 0))),
                          ((m, e, c), ((0, 0), (1, 0), (1, 1))), ((m, c, d), ((0, 0), (1, 1), (0, 1)))):
                for p, q in zip(P, uv):
                    rows.append([*p, *q, *col])
        return np.array(rows, np.float32)

    def release(self) -> None:
        self.ctx.release()
