# bench/crosscheck_cycles.py — build one of our scene files in Blender Cycles and render it.
#
# Runs inside Blender (tested with Debian's blender 3.4.1):
#   blender -b --factory-startup -P bench/crosscheck_cycles.py -- \
#       --scene scenes/cornell-box/scene.json --size 128x128 --spp 4096 --seed 0 \
#       --out build/crosscheck/cycles.exr
#   ... --runs N --out DIR/cycles-{run}.exr   # N renders in this one process (see --runs)
#
# Purpose: an independent radiometric reference for our path tracer (bench/crosscheck.sh,
# docs/crosscheck.md). Everything in Cycles that would make its image differ in expectation
# from an unbiased path tracer of the same scene is switched off here:
#   - colour management: view "Standard", look None, exposure 0, gamma 1, film exposure 1;
#     the output is a 32-bit float EXR of the render result (scene-linear, no view transform);
#   - no clamping, no glossy filter, no denoising, no adaptive sampling, no path guiding,
#     no light threshold, no fast GI, no camera/distance culling, 64 bounces of every kind;
#   - pixel filter: box, 1 px wide (one uniform sample position per pixel area per sample, but
#     for Cycles' sample 0, which is at the pixel's centre: see --sample-offset);
#   - world: black, strength 0 (unless the scene has an environment radiance);
#   - emitters: Emission shader (strength 1 = radiance equal to its colour; bench/crosscheck.sh
#     checks that with --probe-emission) mixed with "nothing" (black, no BSDF) on back faces
#     unless the material is two-sided, and no BSDF on emitters whose albedo is zero;
#   - diffuse: Diffuse BSDF with roughness 0 (Lambertian).
# Coordinates: ours are right-handed Y-up; Blender is right-handed Z-up. Points map with the
# proper rotation (x, y, z) -> (x, -z, y), which keeps handedness (no mirroring) and winding.
#
# Supported scene subset (enough for the Cornell box and simple test scenes): materials of
# type "diffuse" (albedo, emission, two_sided), shapes "quad", "triangles"/inline meshes
# ("positions"/"vertices" + "indices"), "box", "sphere" (tessellated: approximate!), each
# with an optional transform {translate, rotate_deg (XYZ, degrees), scale}. Anything else is
# an error, never silently skipped.
import argparse
import json
import math
import os
import sys
import time

import bpy


def fail(msg):
    print("crosscheck_cycles: error: " + msg, file=sys.stderr)
    sys.exit(2)


def to_blender(p):
    """Our Y-up point/vector -> Blender Z-up (proper rotation about +x by +90 degrees)."""
    return (float(p[0]), -float(p[2]), float(p[1]))


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    ap = argparse.ArgumentParser(prog="crosscheck_cycles.py")
    ap.add_argument("--scene", help="our scene JSON")
    ap.add_argument("--size", default="128x128", help="WxH (or a single number for a square)")
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--runs", type=int, default=1,
                    help="render N images in this one Blender process (the scene built once), "
                         "run k with Cycles' seed run_seed(seed, k), to --out with '{run}' "
                         "replaced by k; for per-pixel statistics over seeds (bench/"
                         "direct_light_cycles.py) without Blender's start-up per image")
    ap.add_argument("--max-bounces", type=int, default=64)
    ap.add_argument("--sample-offset", type=int, default=0,
                    help="Cycles' sample offset: the first sample's index. Cycles takes sample 0 at "
                         "the pixel's centre (integrate_camera_sample: filter_u = filter_v = 0.5) and "
                         "every other one at a random position, so a 1-spp image over seeds samples "
                         "the pixel's area only with an offset of 1 or more")
    ap.add_argument("--threads", type=int, default=0, help="0 = all cores")
    ap.add_argument("--out", required=True, help="output EXR (32-bit float RGBA)")
    ap.add_argument("--probe-emission", choices=("front", "back"),
                    help="instead of a scene: camera looking straight at the front (or back) of a "
                         "big one-sided emissive quad of colour (1,1,1), strength 1; the EXR must "
                         "read 1.0 (front) or 0.0 (back)")
    ap.add_argument("--light-sampling", choices=("on", "off"), default="on",
                    help="off: emitters are found by BSDF sampling only (no next-event estimation "
                         "on mesh lights) — a diagnostic for Cycles' light-sampling path")
    ap.add_argument("--subdivide-emitters", type=int, default=1, metavar="N",
                    help="split each emissive quad into NxN smaller quads (same geometry; changes "
                         "which triangle-light sampling Cycles picks) — a diagnostic")
    ap.add_argument("--save-blend", help="also save the built .blend here (for inspection)")
    a = ap.parse_args(argv)
    if "x" in a.size:
        w, h = a.size.lower().split("x")
        a.width, a.height = int(w), int(h)
    else:
        a.width = a.height = int(a.size)
    if not a.probe_emission and not a.scene:
        ap.error("--scene is required (or --probe-emission)")
    if a.runs < 1 or (a.runs > 1 and "{run}" not in a.out):
        ap.error("--runs N needs N >= 1, and '{run}' in --out when N > 1")
    return a


def run_seed(seed, k):
    """Cycles' seed of run k: run 0 is --seed itself; the others a 32-bit mix (murmur3's
    finaliser) of (seed, k), 31 bits (the property's range). Cycles 3.4 XORs its seed into
    every pixel's hash, so consecutive seeds would differ only in the hash's low bits."""
    if k == 0:
        return seed
    h = (seed * 0x9E3779B1 + k) & 0xFFFFFFFF
    h ^= h >> 16
    h = (h * 0x85EBCA6B) & 0xFFFFFFFF
    h ^= h >> 13
    h = (h * 0xC2B2AE35) & 0xFFFFFFFF
    h ^= h >> 16
    return h & 0x7FFFFFFF


# --------------------------------------------------------------------------- transforms
def mat3_rot_xyz(deg):
    """Rotation matrix for rotate_deg [rx, ry, rz], applied X then Y then Z (R = Rz Ry Rx)."""
    rx, ry, rz = (math.radians(float(v)) for v in deg)
    cx, sx, cy, sy, cz, sz = math.cos(rx), math.sin(rx), math.cos(ry), math.sin(ry), math.cos(rz), math.sin(rz)
    Rx = [[1, 0, 0], [0, cx, -sx], [0, sx, cx]]
    Ry = [[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]]
    Rz = [[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]]

    def mul(A, B):
        return [[sum(A[i][k] * B[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
    return mul(Rz, mul(Ry, Rx))


def make_xform(t):
    """Object -> world point map of our {translate, rotate_deg, scale} (scale, rotate, translate)."""
    if not t:
        return lambda p: tuple(float(c) for c in p)
    tr = t.get("translate", [0, 0, 0])
    R = mat3_rot_xyz(t.get("rotate_deg", [0, 0, 0]))
    sc = t.get("scale", 1)
    s = [float(sc)] * 3 if isinstance(sc, (int, float)) else [float(c) for c in sc]
    for k in t:
        if k not in ("translate", "rotate_deg", "scale"):
            fail("transform key '%s' not supported" % k)

    def f(p):
        q = [s[i] * float(p[i]) for i in range(3)]
        return tuple(sum(R[i][j] * q[j] for j in range(3)) + float(tr[i]) for i in range(3))
    return f


# --------------------------------------------------------------------------- materials
LIGHT_SAMPLING = True


def new_material(name, spec):
    kind = spec.get("type", "diffuse")
    if kind != "diffuse":
        fail("material '%s': type '%s' not supported (only diffuse)" % (name, kind))
    for k in spec:
        if k not in ("type", "albedo", "emission", "two_sided", "two_sided_emission"):
            fail("material '%s': key '%s' not supported by the cross-check" % (name, k))
    albedo = [float(c) for c in spec.get("albedo", [0, 0, 0])]
    emission = [float(c) for c in spec.get("emission", [0, 0, 0])]
    two_sided = bool(spec.get("two_sided", spec.get("two_sided_emission", False)))
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    mat.cycles.sample_as_light = LIGHT_SAMPLING  # "multiple importance" for mesh lights (3.4 name)
    nt = mat.node_tree
    for n in list(nt.nodes):
        nt.nodes.remove(n)
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    out.target = "CYCLES"
    surf = None
    if any(c > 0 for c in albedo):
        d = nt.nodes.new("ShaderNodeBsdfDiffuse")
        d.inputs["Color"].default_value = (*albedo, 1.0)
        d.inputs["Roughness"].default_value = 0.0  # Lambert, not Oren-Nayar
        surf = d.outputs["BSDF"]
    if any(c > 0 for c in emission):
        e = nt.nodes.new("ShaderNodeEmission")
        e.inputs["Color"].default_value = (*emission, 1.0)
        e.inputs["Strength"].default_value = 1.0
        em = e.outputs["Emission"]
        if not two_sided:
            # Back faces emit nothing: Mix(fac = Backfacing, front = emission, back = no closure).
            geo = nt.nodes.new("ShaderNodeNewGeometry")
            mix = nt.nodes.new("ShaderNodeMixShader")
            nt.links.new(geo.outputs["Backfacing"], mix.inputs["Fac"])
            nt.links.new(em, mix.inputs[1])  # fac 0 (front face)
            # mix.inputs[2] (fac 1, back face) stays unconnected = no closure = black
            em = mix.outputs["Shader"]
        if surf is not None:
            add = nt.nodes.new("ShaderNodeAddShader")
            nt.links.new(surf, add.inputs[0])
            nt.links.new(em, add.inputs[1])
            surf = add.outputs["Shader"]
        else:
            surf = em
    if surf is not None:
        nt.links.new(surf, out.inputs["Surface"])
    # else: nothing connected -> black, absorbs everything (albedo 0, no emission)
    return mat


# --------------------------------------------------------------------------- shapes
def add_mesh(name, verts, tris, mat):
    me = bpy.data.meshes.new(name)
    me.from_pydata([to_blender(v) for v in verts], [], [tuple(t) for t in tris])
    me.validate()
    me.update()
    for p in me.polygons:
        p.use_smooth = False
    me.materials.append(mat)
    ob = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def box_mesh(lo, hi):
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    v = [(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0),
         (x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)]
    # outward-facing, counter-clockwise seen from outside
    quads = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (3, 7, 6, 2), (0, 4, 7, 3), (1, 2, 6, 5)]
    tris = []
    for a, b, c, d in quads:
        tris += [(a, b, c), (a, c, d)]
    return v, tris


def sphere_mesh(center, radius, nu=256, nv=128):
    verts, tris = [], []
    for j in range(nv + 1):
        th = math.pi * j / nv
        for i in range(nu):
            ph = 2 * math.pi * i / nu
            verts.append((center[0] + radius * math.sin(th) * math.cos(ph),
                          center[1] + radius * math.cos(th),
                          center[2] + radius * math.sin(th) * math.sin(ph)))
    for j in range(nv):
        for i in range(nu):
            a, b = j * nu + i, j * nu + (i + 1) % nu
            c, d = a + nu, b + nu
            tris += [(a, b, d), (a, d, c)]  # outward
    return verts, tris


def subdivide_quad(q, n):
    """n x n grid of quads over the bilinear patch q (exact for planar parallelograms)."""
    def lerp(a, b, t):
        return tuple(a[i] + (b[i] - a[i]) * t for i in range(3))
    verts = []
    for j in range(n + 1):
        l, r = lerp(q[0], q[3], j / n), lerp(q[1], q[2], j / n)
        for i in range(n + 1):
            verts.append(lerp(l, r, i / n))
    tris = []
    for j in range(n):
        for i in range(n):
            a, b = j * (n + 1) + i, j * (n + 1) + i + 1
            c, d = b + n + 1, a + n + 1
            tris += [(a, b, c), (a, c, d)]
    return verts, tris


def build_scene(scene_json, mats, subdiv_emitters=1):
    shapes = scene_json.get("shapes", [])
    sj_materials = scene_json.get("materials", {})
    for idx, sh in enumerate(shapes):
        kind = sh.get("type")
        name = sh.get("name") or "%s_%d" % (kind, idx)
        mname = sh.get("material")
        if mname not in mats:
            fail("/shapes/%d: unknown material '%s'" % (idx, mname))
        xf = make_xform(sh.get("transform"))
        if kind == "quad":
            vs = sh["vertices"]
            if len(vs) != 4:
                fail("/shapes/%d: a quad needs 4 vertices" % idx)
            verts, tris = [xf(v) for v in vs], [(0, 1, 2), (0, 2, 3)]
            if subdiv_emitters > 1 and any(c > 0 for c in sj_materials[mname].get("emission", [0])):
                verts, tris = subdivide_quad(verts, subdiv_emitters)
        elif kind in ("triangles", "mesh") and "file" not in sh:
            vs = sh.get("positions", sh.get("vertices"))
            ind = sh["indices"]
            if ind and isinstance(ind[0], list):
                tris = [tuple(t) for t in ind]
            else:
                tris = [tuple(ind[i:i + 3]) for i in range(0, len(ind), 3)]
            verts = [xf(v) for v in vs]
        elif kind == "box":
            lo = sh.get("min")
            hi = sh.get("max")
            if lo is None or hi is None:
                c, s = sh["center"], sh["size"]
                lo = [c[i] - 0.5 * s[i] for i in range(3)]
                hi = [c[i] + 0.5 * s[i] for i in range(3)]
            v, tris = box_mesh(lo, hi)
            verts = [xf(p) for p in v]
        elif kind == "sphere":
            print("crosscheck_cycles: warning: /shapes/%d: sphere tessellated (approximate)" % idx)
            v, tris = sphere_mesh(sh["center"], float(sh["radius"]))
            verts = [xf(p) for p in v]
        else:
            fail("/shapes/%d: shape type '%s' not supported by the cross-check" % (idx, kind))
        add_mesh(name, verts, tris, mats[mname])


def probe_scene(side):
    """A 2000x2000 quad at z=1000 facing -z, emission (1,1,1) strength 1, seen from its front
    (camera at the origin) or its back (camera at z=2000)."""
    mat = new_material("probe", {"type": "diffuse", "albedo": [0, 0, 0], "emission": [1, 1, 1]})
    # counter-clockwise seen from the camera at the origin looking +z (normal -z)
    q = [(-1000, -1000, 1000), (-1000, 1000, 1000), (1000, 1000, 1000), (1000, -1000, 1000)]
    add_mesh("probe", q, [(0, 1, 2), (0, 2, 3)], mat)
    z = 0 if side == "front" else 2000
    return {"position": [0, 0, z], "look_at": [0, 0, 1000], "up": [0, 1, 0], "fov_deg": 30}


# --------------------------------------------------------------------------- camera, render
def setup_camera(cam_spec, width, height):
    import mathutils
    cd = bpy.data.cameras.new("cam")
    cd.type = "PERSP"
    cd.sensor_fit = "VERTICAL"
    cd.angle_y = math.radians(float(cam_spec.get("fov_deg", 39.3077)))
    cd.shift_x = cd.shift_y = 0.0
    cd.clip_start = 1e-3
    cd.clip_end = 1e7
    ob = bpy.data.objects.new("cam", cd)
    bpy.context.scene.collection.objects.link(ob)
    pos = mathutils.Vector(to_blender(cam_spec["position"]))
    at = mathutils.Vector(to_blender(cam_spec["look_at"]))
    up = mathutils.Vector(to_blender(cam_spec.get("up", [0, 1, 0])))
    fwd = (at - pos).normalized()
    right = fwd.cross(up).normalized()   # same construction as our camera
    cup = right.cross(fwd)
    # Blender camera: looks along local -Z, local +Y is up, local +X is right.
    rot = mathutils.Matrix(((right.x, cup.x, -fwd.x),
                            (right.y, cup.y, -fwd.y),
                            (right.z, cup.z, -fwd.z)))
    ob.matrix_world = mathutils.Matrix.Translation(pos) @ rot.to_4x4()
    bpy.context.scene.camera = ob
    return ob


def setup_render(a, env_radiance):
    sc = bpy.context.scene
    r = sc.render
    r.engine = "CYCLES"
    r.resolution_x, r.resolution_y, r.resolution_percentage = a.width, a.height, 100
    r.pixel_aspect_x = r.pixel_aspect_y = 1.0
    r.use_border = False
    r.use_motion_blur = False
    r.use_compositing = False
    r.use_sequencer = False
    r.use_multiview = False
    r.film_transparent = False
    r.dither_intensity = 0.0
    r.use_persistent_data = False
    r.threads_mode = "FIXED" if a.threads else "AUTO"
    if a.threads:
        r.threads = a.threads
    c = sc.cycles
    c.device = "CPU"
    c.feature_set = "SUPPORTED"
    c.shading_system = False  # SVM, not OSL
    c.samples = a.spp
    c.seed = a.seed
    c.use_animated_seed = False
    c.sample_offset = a.sample_offset
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.time_limit = 0.0
    c.sampling_pattern = "PROGRESSIVE_MULTI_JITTER"
    c.auto_scrambling_distance = False
    c.scrambling_distance = 1.0
    c.use_guiding = False
    c.use_fast_gi = False
    c.use_camera_cull = False
    c.use_distance_cull = False
    c.sample_clamp_direct = 0.0
    c.sample_clamp_indirect = 0.0
    c.blur_glossy = 0.0
    c.light_sampling_threshold = 0.0
    c.caustics_reflective = True
    c.caustics_refractive = True
    c.min_light_bounces = 0
    c.min_transparent_bounces = 0
    for k in ("max_bounces", "diffuse_bounces", "glossy_bounces", "transmission_bounces",
              "volume_bounces", "transparent_max_bounces"):
        setattr(c, k, a.max_bounces)
    c.pixel_filter_type = "BOX"
    c.filter_width = 1.0
    c.film_exposure = 1.0
    c.film_transparent_glass = False
    # colour management: identity
    sc.display_settings.display_device = "sRGB"
    sc.view_settings.view_transform = "Standard"
    sc.view_settings.look = "None"
    sc.view_settings.exposure = 0.0
    sc.view_settings.gamma = 1.0
    sc.view_settings.use_curve_mapping = False
    # world: constant radiance (black by default; the factory world is grey 0.05!)
    w = bpy.data.worlds.new("env")
    w.use_nodes = True
    bg = w.node_tree.nodes["Background"]
    env = [float(x) for x in env_radiance]
    bg.inputs["Color"].default_value = (*env, 1.0)
    bg.inputs["Strength"].default_value = 1.0 if any(env) else 0.0
    sc.world = w
    # output
    im = r.image_settings
    im.file_format = "OPEN_EXR"
    im.color_mode = "RGBA"
    im.color_depth = "32"
    im.exr_codec = "ZIP"
    r.use_file_extension = False
    vl = sc.view_layers[0]
    vl.use_pass_combined = True
    vl.samples = 0


def main():
    global LIGHT_SAMPLING
    a = parse_args()
    LIGHT_SAMPLING = a.light_sampling == "on"
    # empty scene: the factory startup has a cube, a light and a camera
    for ob in list(bpy.data.objects):
        bpy.data.objects.remove(ob, do_unlink=True)
    if a.probe_emission:
        cam = probe_scene(a.probe_emission)
        env = [0, 0, 0]
    else:
        with open(a.scene) as f:
            sj = json.load(f)
        mats = {n: new_material(n, m) for n, m in sj.get("materials", {}).items()}
        build_scene(sj, mats, a.subdivide_emitters)
        cam = sj["camera"]
        env = (sj.get("environment") or {}).get("radiance", [0, 0, 0])
    setup_camera(cam, a.width, a.height)
    setup_render(a, env)
    out = os.path.abspath(a.out)
    os.makedirs(os.path.dirname(out), exist_ok=True)
    bpy.context.scene.render.filepath = out
    if a.save_blend:
        bpy.ops.wm.save_as_mainfile(filepath=os.path.abspath(a.save_blend))
    # Timed: Cycles' scene sync, BVH build and sampling (not Blender's start-up, not the EXR
    # write), as restird's time_ms covers its frame's rendering.
    for k in range(a.runs):
        seed = run_seed(a.seed, k)
        bpy.context.scene.cycles.seed = seed
        path = out.replace("{run}", str(k))
        t0 = time.monotonic()
        bpy.ops.render.render(write_still=False)
        render_ms = (time.monotonic() - t0) * 1e3
        bpy.data.images["Render Result"].save_render(path)
        if not os.path.exists(path):
            fail("Blender did not write " + path)
        print("crosscheck_cycles: wrote %s (%dx%d, %d spp, seed %d)" % (path, a.width, a.height, a.spp, seed))
        print("crosscheck_cycles: render_ms %.3f" % render_ms)


main()
