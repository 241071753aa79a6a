"""Indirect irradiance at surface points, rendered by Mitsuba 3: the outside renderer the
bounce reference is checked against (reference/tests/mitsuba.rs writes the input).

Input JSON (argv[1]): {"meshes": [{"obj": path, "albedo": [r,g,b], "double_sided": bool}],
"lights": [{"position": [x,y,z], "intensity": [r,g,b]}], "points": [{"position", "normal",
"albedo"}], "bounces": K, "spp": N, "batches": B}. Output JSON (argv[2]): per point the mean and
standard error of E_ind over B independent batches.

A radiance meter just off each point looks back at it along the normal. Mitsuba's path
integrator with max_depth 2 gives the light reflected once (direct illumination); with
max_depth K + 2 it adds K indirect bounces. For a Lambertian surface of albedo rho the outgoing
radiance is rho/pi * E, so E_ind = pi / rho * (L_{K+2} - L_2).
"""

import json
import math
import sys

import mitsuba as mi

mi.set_variant("scalar_rgb")


def main():
    with open(sys.argv[1]) as f:
        job = json.load(f)
    scene = {"type": "scene"}
    for i, m in enumerate(job["meshes"]):
        bsdf = {"type": "diffuse", "reflectance": {"type": "rgb", "value": m["albedo"]}}
        if m["double_sided"]:
            bsdf = {"type": "twosided", "material": bsdf}
        scene[f"mesh_{i}"] = {"type": "obj", "filename": m["obj"], "face_normals": True, "bsdf": bsdf}
    for i, l in enumerate(job["lights"]):
        scene[f"light_{i}"] = {
            "type": "point",
            "position": l["position"],
            "intensity": {"type": "rgb", "value": l["intensity"]},
        }
    offset = job.get("offset", 1e-3)
    for i, p in enumerate(job["points"]):
        n = p["normal"]
        scene[f"sensor_{i}"] = {
            "type": "radiancemeter",
            "origin": [p["position"][k] + offset * n[k] for k in range(3)],
            "direction": [-n[k] for k in range(3)],
            "film": {
                "type": "hdrfilm",
                "width": 1,
                "height": 1,
                "rfilter": {"type": "box"},
                "pixel_format": "rgb",
            },
            "sampler": {"type": "independent", "sample_count": job["spp"]},
        }
    loaded = mi.load_dict(scene)
    direct = mi.load_dict({"type": "path", "max_depth": 2})
    full = mi.load_dict({"type": "path", "max_depth": job["bounces"] + 2, "rr_depth": 1000})
    out = []
    for i, p in enumerate(job["points"]):
        batches = []
        for b in range(job["batches"]):
            seed = 1 + 2 * b
            l2 = mi.render(loaded, sensor=i, integrator=direct, spp=job["spp"], seed=seed)
            lk = mi.render(loaded, sensor=i, integrator=full, spp=job["spp"], seed=seed + 1)
            l2, lk = [float(v) for v in l2.array], [float(v) for v in lk.array]
            batches.append([math.pi / p["albedo"][c] * (lk[c] - l2[c]) for c in range(3)])
        nb = len(batches)
        mean = [sum(b[c] for b in batches) / nb for c in range(3)]
        var = [sum((b[c] - mean[c]) ** 2 for b in batches) / (nb - 1) for c in range(3)]
        out.append({"mean": mean, "stderr": [math.sqrt(v / nb) for v in var]})
    with open(sys.argv[2], "w") as f:
        json.dump({"mitsuba": mi.__version__, "points": out}, f)


if __name__ == "__main__":
    main()
