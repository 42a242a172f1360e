"""The report's pictures of the scene: each view's colour image as a thumbnail, the fused
primitives rendered as solids (MuJoCo, offscreen) with the bodies they matched, and the support
graph drawn as a graph (thesis 3.2.2, 3.3.1: nodes are primitives, edges SUPP(a, b) with
occ(e); against the truth, false positives and missed edges marked)."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

#: colours of the primitive kinds where a primitive carries no colour of its own
KIND_RGB = {"plane": (0.75, 0.75, 0.7), "cylinder": (0.3, 0.55, 0.9),
            "sphere": (0.9, 0.5, 0.2), "box": (0.45, 0.75, 0.4)}  # fmt: skip
#: the support graph's marks: the verdict of an edge, the state of a primitive
EDGE_STYLE = {"true": ("#2a8f2a", "-"), "false_positive": ("#d62728", "-"),
              "not_judged": ("#7f7f7f", "-"), "missed": ("#7f7f7f", "--")}  # fmt: skip
NODE_FILL = {"stable": "#dce9f7", "unstable": "#f4b6b6", "unresolved": "#f7d98b"}


# -- what an episode keeps --------------------------------------------------------------------


def thumbnail(rgb: np.ndarray | None, path: Path, root: Path, width: int = 320) -> str:
    """``rgb`` (h, w, 3 uint8) as a JPEG ``width`` wide at ``path``; its path relative to
    ``root`` ("" without an image)."""
    from PIL import Image

    if rgb is None or np.asarray(rgb).ndim != 3:
        return ""
    image = Image.fromarray(np.ascontiguousarray(rgb, dtype=np.uint8))
    image = image.resize((width, max(1, round(image.height * width / image.width))))
    path.parent.mkdir(parents=True, exist_ok=True)
    image.save(path, quality=85)
    return str(path.relative_to(root))


def solid(p) -> dict:
    """A primitive's solid for the rendering: its OBB (centre, rotation, full extent) and, for
    cylinders and spheres, the fitted model (axis, radius, height); its colour in [0, 1]."""
    out = {"rotation": np.round(np.asarray(p.obb.rotation, float), 4).tolist(),
           "colour": [round(float(c) / 255, 3) for c in np.asarray(p.colour)]}  # fmt: skip
    m = p.model
    if m.kind == "cylinder":
        out["model"] = {"center": np.round(m.center, 4).tolist(),
                        "axis": np.round(m.axis, 4).tolist(), "radius": round(float(m.radius), 4),
                        "height": round(float(m.height), 4)}  # fmt: skip
    elif m.kind == "sphere":
        out["model"] = {"center": np.round(m.center, 4).tolist(),
                        "radius": round(float(m.radius), 4)}  # fmt: skip
    return out


def support_verdicts(edges, bodies: dict[int, str], scores) -> list[dict]:
    """Each fused support edge with occ(e), the bodies of its ends ('#id': none) and its
    verdict: "true", "false_positive", or "not_judged" (an edge of bodies outside the roi);
    ``scores`` is ``evaluation.score_support``'s for these edges."""
    wrong, judged = set(scores.false_positives), set(scores.edges)
    out = []
    for e in edges:
        a, b = e.supporter, e.supported
        names = (bodies.get(a, f"#{a}"), bodies.get(b, f"#{b}"))
        verdict = (
            "false_positive" if names in wrong else "true" if names in judged else "not_judged"
        )
        out.append({"supporter": e.supporter, "supported": e.supported, "occ": e.occ,
                    "bodies": list(names), "verdict": verdict})  # fmt: skip
    return out


# -- the fused scene, rendered ----------------------------------------------------------------


def scene_xml(primitives: list[dict]) -> str:
    """An MJCF world of the primitives as geoms: boxes and planes as their OBBs (a plane at
    least 1 cm thick), cylinders and spheres as fitted; each in its colour."""
    geoms = []
    for p in primitives:
        rgb = p.get("colour") or []
        if not rgb or max(rgb) < 0.02:
            rgb = KIND_RGB[p["kind"]]
        rgba = " ".join(f"{c:.3f}" for c in (*rgb, 1.0))
        model = p.get("model") or {}
        if p["kind"] == "cylinder" and model:  # MuJoCo turns the geom's z onto the axis
            size = f"{model['radius']:.4f} {max(model['height'], 0.005) / 2:.4f}"
            geoms.append(f'<geom type="cylinder" size="{size}" pos="{_v(model["center"])}" '
                         f'zaxis="{_v(model["axis"])}" rgba="{rgba}"/>')  # fmt: skip
        elif p["kind"] == "sphere" and model:
            geoms.append(f'<geom type="sphere" size="{model["radius"]:.4f}" '
                         f'pos="{_v(model["center"])}" rgba="{rgba}"/>')  # fmt: skip
        else:
            half = np.maximum(np.asarray(p["extent"], float) / 2, 0.005)
            R = np.asarray(p.get("rotation") or np.eye(3), float)  # MuJoCo makes x, y, x×y
            geoms.append(f'<geom type="box" size="{_v(half)}" pos="{_v(p["center"])}" '
                         f'xyaxes="{_v(R[:, 0])} {_v(R[:, 1])}" rgba="{rgba}"/>')  # fmt: skip
    return ('<mujoco><asset><texture type="skybox" builtin="flat" rgb1="0.97 0.97 0.97" '
            'rgb2="0.97 0.97 0.97" width="16" height="16"/></asset>'
            '<visual><global offwidth="1600" offheight="1200"/>'
            '<headlight ambient="0.45 0.45 0.45" diffuse="0.55 0.55 0.55"/></visual>'
            '<worldbody><light pos="0 0 4" dir="0 0 -1" diffuse="0.3 0.3 0.3"/>'
            + "".join(geoms) + "</worldbody></mujoco>")  # fmt: skip


def _v(x) -> str:
    return " ".join(f"{float(a):.4f}" for a in x)


def view_of(roi: list[list[float]], azimuth: float = 200.0, elevation: float = -35.0):
    """A fixed viewpoint on the roi: looking at its centre from ``azimuth`` (deg, 180: from
    −x, where the robot starts) and ``elevation`` (deg, below 0: from above), far enough that
    the roi fills about half the image. Returns (lookat, distance, azimuth, elevation)."""
    lo, hi = np.asarray(roi[0], float), np.asarray(roi[1], float)
    return (lo + hi) / 2, 1.05 * float(np.linalg.norm(hi - lo)) + 0.3, azimuth, elevation


def project(points: np.ndarray, view, size: tuple[int, int], fovy: float) -> np.ndarray:
    """Pixel (u, v) of world points in MuJoCo's free camera ``view`` (lookat, distance,
    azimuth, elevation; ``fovy`` degrees), an image ``size`` = (width, height)."""
    lookat, distance, az, el = view
    a, e = math.radians(az), math.radians(el)
    forward = np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
    eye = lookat - distance * forward
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    d = np.atleast_2d(points) - eye
    z = d @ forward
    f = (size[1] / 2) / math.tan(math.radians(fovy) / 2)
    return np.stack([size[0] / 2 + f * (d @ right) / z, size[1] / 2 - f * (d @ up) / z], 1)


def in_roi(primitives: list[dict], roi: list[list[float]], margin: float = 0.1) -> list[dict]:
    """The primitives whose oriented box meets the roi grown by ``margin`` (the floor and the
    room around it left out: they would fill the picture)."""
    lo, hi = np.asarray(roi[0], float) - margin, np.asarray(roi[1], float) + margin
    kept = []
    for p in primitives:
        R = np.asarray(p.get("rotation") or np.eye(3), float)
        reach = np.abs(R) @ (np.asarray(p["extent"], float) / 2)  # world-axis half extents
        c = np.asarray(p["center"], float)
        if np.all(c + reach >= lo) and np.all(c - reach <= hi):
            kept.append(p)
    return kept


def labels(primitives: list[dict]) -> list[dict]:
    """The primitives to label: each body once, at its primitive with the most inliers (a
    table's top, not each leg), and every primitive that matched no body."""
    best: dict[str, dict] = {}
    for p in primitives:
        body = p.get("body")
        if body and (body not in best or p.get("inliers", 0) > best[body].get("inliers", 0)):
            best[body] = p
    return [p for p in primitives if not p.get("body") or best.get(p["body"]) is p]


def scene_image(primitives: list[dict], roi: list[list[float]], out: Path,
                size: tuple[int, int] = (960, 640)) -> Path:  # fmt: skip
    """``fused_scene.png``: the fused primitives that meet the roi as solids from a fixed
    viewpoint on it, each body labelled once ('#id': a primitive of no body), the roi's box
    drawn."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    import mujoco

    from experiments.report import _plt, _save

    primitives = in_roi(primitives, roi)
    model = mujoco.MjModel.from_xml_string(scene_xml(primitives))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    view = view_of(roi)
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    camera.lookat[:], camera.distance = view[0], view[1]
    camera.azimuth, camera.elevation = view[2], view[3]
    with mujoco.Renderer(model, size[1], size[0]) as renderer:
        renderer.update_scene(data, camera)
        image = renderer.render()
    plt = _plt()
    fig, ax = plt.subplots(figsize=(size[0] / 100, size[1] / 100))
    ax.imshow(image)
    fovy = float(model.vis.global_.fovy)
    lo, hi = np.asarray(roi[0], float), np.asarray(roi[1], float)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])])  # fmt: skip
    uv = project(corners, view, size, fovy)
    for i in range(8):
        for j in range(i + 1, 8):
            if np.count_nonzero(corners[i] != corners[j]) == 1:
                ax.plot(uv[[i, j], 0], uv[[i, j], 1], "--", color="0.4", lw=0.8)
    labelled = labels(primitives)
    if labelled:
        at = project(np.array([p["center"] for p in labelled]), view, size, fovy)
        for p, (u, v) in zip(labelled, at, strict=True):
            if 0 <= u < size[0] and 0 <= v < size[1]:
                name = p.get("body") or f"#{p['id']}"
                ax.annotate(f"{name} ({p['kind']})", (u, v), fontsize=7, ha="center",
                            bbox={"boxstyle": "round,pad=0.2", "fc": "white", "alpha": 0.75,
                                  "lw": 0})  # fmt: skip
    ax.set_xlim(0, size[0])
    ax.set_ylim(size[1], 0)
    ax.axis("off")
    return _save(fig, out / "fused_scene.png")


# -- the support graph --------------------------------------------------------------------------


def support_levels(nodes: list[int], edges: list[tuple[int, int]]) -> dict[int, int]:
    """Each node's height in the support graph: 0 for one nothing supports, else one above its
    highest supporter (cycles broken by visiting each node once per path)."""
    supporters: dict[int, list[int]] = {n: [] for n in nodes}
    for a, b in edges:
        supporters.setdefault(b, []).append(a)
        supporters.setdefault(a, [])
    level: dict[int, int] = {}

    def height(n: int, path: frozenset) -> int:
        if n in level:
            return level[n]
        below = [height(s, path | {n}) for s in supporters[n] if s not in path and s != n]
        level[n] = 1 + max(below) if below else 0
        return level[n]

    for n in supporters:
        height(n, frozenset())
    return level


def support_graph_image(primitives: list[dict], support: list[dict], missed: list[list[str]],
                        out: Path) -> Path:  # fmt: skip
    """``support_graph.png``: the primitives that take part in a support edge as nodes (stacked
    by support height: what stands on something above it), labelled with their body; each
    fused edge an arrow from supporter to supported with occ(e), green where the truth has it,
    red a false positive, grey not judged (outside the roi); the truth's edges not found
    dashed between the bodies' primitives (or the bodies' names where no primitive matched)."""
    from experiments.report import _plt, _save

    by_id = {p["id"]: p for p in primitives}
    edges = [(e["supporter"], e["supported"]) for e in support]
    first_of: dict[str, int] = {}
    for p in primitives:
        if p.get("body"):
            first_of.setdefault(p["body"], p["id"])
    extra: dict[str, int] = {}  # bodies of missed edges that no primitive matched
    missing = []
    for a, b in missed:
        ends = []
        for name in (a, b):
            if name not in first_of and name not in extra:
                extra[name] = -1 - len(extra)
            ends.append(first_of.get(name, extra.get(name)))
        missing.append(tuple(ends))
    nodes = sorted({n for e in edges + missing for n in e})
    level = support_levels(nodes, edges + missing)
    rows: dict[int, list[int]] = {}
    for n in nodes:
        rows.setdefault(level[n], []).append(n)
    pos = {n: ((i + 1) / (len(row) + 1), lv) for lv, row in rows.items() for i, n in enumerate(row)}
    plt = _plt()
    height = max(rows, default=0) + 1
    fig, ax = plt.subplots(figsize=(7.0, 1.2 + 1.3 * height))
    for (a, b), e in zip(edges, support, strict=True):
        colour, ls = EDGE_STYLE[e["verdict"]]
        _arrow(ax, pos[a], pos[b], colour, ls, f"occ {e['occ']}")
    for a, b in missing:
        colour, ls = EDGE_STYLE["missed"]
        _arrow(ax, pos[a], pos[b], colour, ls, "missed")
    names = {v: k for k, v in extra.items()}
    for n, (x, y) in pos.items():
        p = by_id.get(n)
        if p is None:
            label, fill = names[n], "white"
        else:
            label = f"{p.get('body') or '#' + str(n)}\n{p['kind']} #{n}"
            fill = NODE_FILL.get(p.get("state", "stable"), NODE_FILL["stable"])
        box = {"boxstyle": "round,pad=0.35", "fc": fill, "ec": "0.3", "lw": 0.8}
        ax.text(x, y, label, ha="center", va="center", fontsize=7, zorder=3, bbox=box)
    handles = [plt.Line2D([], [], color=c, ls=s, label=k.replace("_", " "))
               for k, (c, s) in EDGE_STYLE.items()]  # fmt: skip
    handles += [plt.Rectangle((0, 0), 1, 1, fc=f, ec="0.3", label=k) for k, f in NODE_FILL.items()]
    ax.legend(handles=handles, fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    ax.set_xlim(0, 1)
    ax.set_ylim(-0.6, height - 0.4)
    ax.axis("off")
    if not nodes:
        ax.text(0.5, 0, "no support edge fused, none in the truth", ha="center")
    ax.set_title("support graph: arrows from supporter to supported")
    return _save(fig, out / "support_graph.png")


def _arrow(ax, a: tuple[float, float], b: tuple[float, float], colour: str, ls: str,
           label: str) -> None:  # fmt: skip
    rad = 0.0 if a[1] != b[1] else 0.3  # side by side: bent, so that it shows
    ax.annotate("", xy=b, xytext=a, zorder=1,
                arrowprops={"arrowstyle": "-|>", "color": colour, "ls": ls, "lw": 1.4,
                            "shrinkA": 18, "shrinkB": 18,
                            "connectionstyle": f"arc3,rad={rad}"})  # fmt: skip
    ax.text((a[0] + b[0]) / 2 + 0.01, (a[1] + b[1]) / 2, label, fontsize=6, color=colour)
