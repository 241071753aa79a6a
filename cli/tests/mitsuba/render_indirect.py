"""Indirect-only radiance images rendered by Mitsuba 3, from a glTF file read by this script's own
loader: the outside reference for `bounce render --indirect only` (cli/tests/render_mitsuba.rs).

The scene is read here from the .gltf JSON and its buffers with `json` and `struct` alone (node
transforms, meshes, accessors, materials' baseColorFactor and doubleSided), not from triangles
bounce's importer wrote, so an import bug cannot hide on both sides.

Input JSON (argv[1]):
  {"gltf": path, "lights": [{"position": [x,y,z], "intensity": [r,g,b]}],
   "camera": {"eye": [..], "target": [..], "fov_y_deg": f}, "width": W, "height": H,
   "spp": N, "batches": B, "out": dir}
Point lights take the glTF KHR_lights_punctual convention: intensity in candela (lm/sr) is
Mitsuba's `point` emitter intensity (W/sr here; the same convention as
reference/tests/mitsuba/irradiance.py).

Output, in `out`:
  - indirect.pfm: linear RGB radiance of the light that bounced at least twice, i.e. Mitsuba's
    all-bounce `path` render minus its direct-only (max_depth = 2) render of the same paths,
    averaged over B independent batches;
  - direct.pfm: the direct-only (max_depth = 2) render, averaged over the batches;
  - mask.pfm: 1 where the ray through the pixel's centre meets a surface, else 0;
  - stats.json: {"mitsuba": version, "variant": ..., "triangles": n, "noise": e, "seconds": s}
    where e estimates the relative L2 standard error of indirect.pfm over the mask (from the
    spread between batches).

A diffuse BSDF per material with the base colour (twosided for doubleSided materials), a
perspective camera with the same vertical field of view and aspect as bounce's (Y up unless the
view runs along Y, then Z, as render/src/camera.rs), and a box pixel filter.

PFM files: "PF\n{w} {h}\n-1.0\n", then little-endian f32 RGB rows, bottom row first.
"""

import base64
import json
import math
import os
import struct
import sys
import time

import drjit as dr
import mitsuba as mi

def pick_variant():
    # scalar_rgb runs anywhere; an LLVM variant is faster but aborts the process (not an
    # exception) when the machine's libLLVM is too old for it, so it is opt-in.
    variant = os.environ.get("BOUNCE_MITSUBA_VARIANT", "scalar_rgb")
    mi.set_variant(variant)
    return variant


# --- glTF ----------------------------------------------------------------------------------

COMPONENT = {5120: ("b", 1), 5121: ("B", 1), 5122: ("h", 2), 5123: ("H", 2), 5125: ("I", 4), 5126: ("f", 4)}
WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


def mat_mul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(4)) for j in range(4)] for i in range(4)]


def node_matrix(node):
    if "matrix" in node:
        m = node["matrix"]  # column-major
        return [[m[c * 4 + r] for c in range(4)] for r in range(4)]
    tx, ty, tz = node.get("translation", [0.0, 0.0, 0.0])
    qx, qy, qz, qw = node.get("rotation", [0.0, 0.0, 0.0, 1.0])
    sx, sy, sz = node.get("scale", [1.0, 1.0, 1.0])
    r = [
        [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
        [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
        [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)],
    ]
    s = (sx, sy, sz)
    t = (tx, ty, tz)
    return [[r[i][0] * s[0], r[i][1] * s[1], r[i][2] * s[2], t[i]] for i in range(3)] + [[0.0, 0.0, 0.0, 1.0]]


def det3(m):
    return (
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    )


class Gltf:
    def __init__(self, path):
        with open(path) as f:
            self.doc = json.load(f)
        base = os.path.dirname(os.path.abspath(path))
        self.buffers = []
        for b in self.doc.get("buffers", []):
            uri = b["uri"]
            if uri.startswith("data:"):
                self.buffers.append(base64.b64decode(uri.split(",", 1)[1]))
            else:
                with open(os.path.join(base, uri), "rb") as f:
                    self.buffers.append(f.read())

    def accessor(self, index):
        a = self.doc["accessors"][index]
        if "sparse" in a:
            raise SystemExit(f"accessor {index}: sparse accessors are not supported")
        fmt, size = COMPONENT[a["componentType"]]
        width = WIDTH[a["type"]]
        view = self.doc["bufferViews"][a["bufferView"]]
        data = self.buffers[view["buffer"]]
        start = view.get("byteOffset", 0) + a.get("byteOffset", 0)
        stride = view.get("byteStride") or size * width
        out = []
        for i in range(a["count"]):
            item = struct.unpack_from("<" + fmt * width, data, start + i * stride)
            out.append(item if width > 1 else item[0])
        return out

    def triangles(self):
        """Per primitive: (world-space triangles as 3 corner tuples, base colour, double-sided)."""
        doc = self.doc
        scene = doc["scenes"][doc.get("scene", 0)]
        identity = [[float(i == j) for j in range(4)] for i in range(4)]
        stack = [(n, identity) for n in scene["nodes"]]
        out = []
        while stack:
            index, parent = stack.pop()
            node = doc["nodes"][index]
            world = mat_mul(parent, node_matrix(node))
            stack.extend((c, world) for c in node.get("children", []))
            if "mesh" not in node:
                continue
            flip = det3(world) < 0.0  # mirrored: the winding turns around
            for prim in doc["meshes"][node["mesh"]]["primitives"]:
                if prim.get("mode", 4) != 4:
                    raise SystemExit(f"mesh {node['mesh']}: only triangle lists are supported")
                pos = self.accessor(prim["attributes"]["POSITION"])
                pos = [
                    tuple(sum(world[r][c] * p[c] for c in range(3)) + world[r][3] for r in range(3))
                    for p in pos
                ]
                idx = self.accessor(prim["indices"]) if "indices" in prim else list(range(len(pos)))
                tris = []
                for k in range(0, len(idx) - 2, 3):
                    a, b, c = idx[k], idx[k + 1], idx[k + 2]
                    if flip:
                        b, c = c, b
                    tris.append((pos[a], pos[b], pos[c]))
                mat = doc["materials"][prim["material"]] if "material" in prim else {}
                pbr = mat.get("pbrMetallicRoughness", {})
                colour = pbr.get("baseColorFactor", [1.0, 1.0, 1.0, 1.0])[:3]
                if any(x > 0.0 for x in mat.get("emissiveFactor", [0.0, 0.0, 0.0])):
                    raise SystemExit(f"material {mat.get('name')}: emission is not modelled here")
                out.append((tris, colour, bool(mat.get("doubleSided", False))))
        return out


def write_ply(path, tris):
    with open(path, "wb") as f:
        head = (
            "ply\nformat binary_little_endian 1.0\n"
            f"element vertex {3 * len(tris)}\nproperty float x\nproperty float y\nproperty float z\n"
            f"element face {len(tris)}\nproperty list uchar int vertex_indices\nend_header\n"
        )
        f.write(head.encode())
        for t in tris:
            for p in t:
                f.write(struct.pack("<3f", *p))
        for k in range(len(tris)):
            f.write(struct.pack("<B3i", 3, 3 * k, 3 * k + 1, 3 * k + 2))


# --- images --------------------------------------------------------------------------------


def pixels(img, width, height, channels):
    """A render (or any H × W × C tensor) as rows top to bottom of per-pixel lists."""
    flat = list(dr.ravel(img)) if hasattr(dr, "ravel") else list(img.array)
    flat = [float(x) for x in flat]
    return [[flat[(y * width + x) * channels:(y * width + x + 1) * channels] for x in range(width)] for y in range(height)]


def write_pfm(path, rows, width, height):
    with open(path, "wb") as f:
        f.write(f"PF\n{width} {height}\n-1.0\n".encode())
        for row in reversed(rows):
            for px in row:
                f.write(struct.pack("<3f", *(px + [px[0]] * (3 - len(px)))[:3]))


def main():
    with open(sys.argv[1]) as f:
        job = json.load(f)
    started = time.time()
    variant = pick_variant()
    out_dir = job["out"]
    os.makedirs(out_dir, exist_ok=True)
    scene = {"type": "scene"}
    count = 0
    for i, (tris, colour, double_sided) in enumerate(Gltf(job["gltf"]).triangles()):
        if not tris:
            continue
        ply = os.path.join(out_dir, f"prim{i}.ply")
        write_ply(ply, tris)
        count += len(tris)
        bsdf = {"type": "diffuse", "reflectance": {"type": "rgb", "value": colour}}
        if double_sided:
            bsdf = {"type": "twosided", "material": bsdf}
        scene[f"prim_{i}"] = {"type": "ply", "filename": ply, "face_normals": True, "bsdf": bsdf}
    for i, l in enumerate(job["lights"]):
        scene[f"light_{i}"] = {
            "type": "point",
            "position": l["position"],
            "intensity": {"type": "rgb", "value": l["intensity"]},
        }
    w, h = job["width"], job["height"]
    cam = job["camera"]
    eye, target = cam["eye"], cam["target"]
    d = [target[k] - eye[k] for k in range(3)]
    up = [0, 0, 1] if abs(d[1]) / math.sqrt(sum(x * x for x in d)) > 0.99 else [0, 1, 0]
    scene["sensor"] = {
        "type": "perspective",
        "fov": cam["fov_y_deg"],
        "fov_axis": "y",
        "near_clip": 1e-3,
        "to_world": mi.ScalarTransform4f().look_at(origin=eye, target=target, up=up),
        "film": {
            "type": "hdrfilm",
            "width": w,
            "height": h,
            "rfilter": {"type": "box"},
            "pixel_format": "rgb",
        },
        "sampler": {"type": "independent", "sample_count": job["spp"]},
    }
    loaded = mi.load_dict(scene)
    direct = mi.load_dict({"type": "path", "max_depth": 2})
    full = mi.load_dict({"type": "path", "max_depth": job.get("max_depth", 100)})
    batches = []
    direct_sum = None
    for b in range(job["batches"]):
        # The same seed for both: the direct-only render is then exactly the first part of the
        # all-bounce one's paths, and their difference has no direct-light noise in it.
        seed = 17 + b
        lk = mi.render(loaded, integrator=full, spp=job["spp"], seed=seed)
        l2 = mi.render(loaded, integrator=direct, spp=job["spp"], seed=seed)
        batches.append(pixels(lk - l2, w, h, 3))
        d = pixels(l2, w, h, 3)
        direct_sum = d if direct_sum is None else [[[a + b for a, b in zip(p, q)] for p, q in zip(r, s)] for r, s in zip(direct_sum, d)]
    nb = len(batches)
    mean = [[[sum(bt[y][x][c] for bt in batches) / nb for c in range(3)] for x in range(w)] for y in range(h)]

    # The hit mask: one ray through each pixel's centre.
    sensor = loaded.sensors()[0]
    mask = []
    for y in range(h):
        row = []
        for x in range(w):
            ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f((x + 0.5) / w, (y + 0.5) / h), mi.Point2f(0.5, 0.5))
            si = loaded.ray_intersect(ray)
            row.append([1.0 if bool(dr.all(si.is_valid())) else 0.0])
        mask.append(row)

    # Standard error of the mean image, relative to it, over the mask.
    num = den = 0.0
    for y in range(h):
        for x in range(w):
            if mask[y][x][0] == 0.0:
                continue
            for c in range(3):
                m = mean[y][x][c]
                if nb > 1:
                    var = sum((bt[y][x][c] - m) ** 2 for bt in batches) / (nb - 1)
                    num += var / nb
                den += m * m
    noise = math.sqrt(num / den) if nb > 1 and den > 0 else None
    write_pfm(os.path.join(out_dir, "indirect.pfm"), mean, w, h)
    direct = [[[c / nb for c in px] for px in row] for row in direct_sum]
    write_pfm(os.path.join(out_dir, "direct.pfm"), direct, w, h)
    write_pfm(os.path.join(out_dir, "mask.pfm"), mask, w, h)
    with open(os.path.join(out_dir, "stats.json"), "w") as f:
        json.dump(
            {
                "mitsuba": mi.__version__,
                "variant": variant,
                "triangles": count,
                "noise": noise,
                "seconds": time.time() - started,
            },
            f,
        )


if __name__ == "__main__":
    main()
