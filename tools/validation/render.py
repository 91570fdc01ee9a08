"""Renders one scene of the validation set with Blender's Cycles, and its
geometric truth.

    nice -n 10 blender -b --factory-startup -noaudio -P tools/validation/render.py -- \
        --spec tools/validation/scenes.yaml --scene grey_a --out /tmp/vs [--samples N] [--frames 0,2]

Per frame it writes <out>/<scene>/f<k>_<pass>_0001.exr (float RGB, one light
group each: `sun` (the sun and what it inter-reflects), `sky` (the sky dome),
`proj` (the projector alone), cropped to the scene's region of interest) and
<out>/<scene>/truth.json (rig poses, every beam's hit point by ray casting
against the very mesh that is rendered, its pixel and visibility). pack.py
turns them into the committed set. Threads: one (-t 1 is not needed; set
here), so that other work on the machine goes on.
"""
import json
import math
import os
import sys

import bpy
import mathutils
import numpy as np
from mathutils.bvhtree import BVHTree

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import geometry as G  # noqa: E402
import yaml  # noqa: E402


def args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    out = {"samples": None, "frames": None, "threads": 1, "seed_offset": 0, "roi": None, "bounces": None,
           "passes": None}
    i = 0
    while i < len(argv):
        k, v = argv[i], argv[i + 1]
        out[k.lstrip("-").replace("-", "_")] = v
        i += 2
    return out


def matrix(T):
    return mathutils.Matrix([list(r) for r in T])


def new_image(name, arr, interpolation):
    """A float image from an array of rows (row 0 at v = 0), Non-Color."""
    h, w = arr.shape[:2]
    img = bpy.data.images.new(name, w, h, alpha=False, float_buffer=True)
    # Before the pixels: changing the colour space regenerates a generated
    # image's buffer (it came back black).
    img.colorspace_settings.name = "Non-Color"
    rgba = np.ones((h, w, 4), np.float32)
    if arr.ndim == 2:
        rgba[..., :3] = arr[..., None]
    else:
        rgba[..., :3] = arr
    img.pixels.foreach_set(rgba.ravel())
    return img, interpolation


def mesh_object(name, verts, tris, uvs):
    me = bpy.data.meshes.new(name)
    me.from_pydata(np.asarray(verts, float).tolist(), [], np.asarray(tris).tolist())
    uv = me.uv_layers.new(name="uv")
    loop_vert = np.empty(len(me.loops), np.int32)
    me.loops.foreach_get("vertex_index", loop_vert)
    uv.data.foreach_set("uv", np.asarray(uvs, np.float32)[loop_vert].ravel())
    me.polygons.foreach_set("use_smooth", np.zeros(len(me.polygons), bool))  # flat facets
    me.update()
    ob = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def textured_material(name, image, interpolation, roughness=0.9, specular=0.15):
    """Principled BSDF (Disney diffuse with a weak sheen, not Lambert)."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nt = mat.node_tree
    bsdf = nt.nodes["Principled BSDF"]
    tex = nt.nodes.new("ShaderNodeTexImage")
    tex.image = image
    tex.interpolation = interpolation
    uvn = nt.nodes.new("ShaderNodeUVMap")
    uvn.uv_map = "uv"
    nt.links.new(uvn.outputs["UV"], tex.inputs["Vector"])
    nt.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    bsdf.inputs["Roughness"].default_value = roughness
    bsdf.inputs["Specular"].default_value = specular
    return mat


def mask_material(image, origin_rig):
    """The gobo: opaque to the projector's shadow rays by its transmission
    image, transparent to every other ray (the sun's shadow rays among them:
    they do not come from the projector's origin)."""
    mat = bpy.data.materials.new("mask")
    mat.use_nodes = True
    nt = mat.node_tree
    for n in list(nt.nodes):
        nt.nodes.remove(n)
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    geo = nt.nodes.new("ShaderNodeNewGeometry")
    coord = nt.nodes.new("ShaderNodeTexCoord")
    to_obj = nt.nodes.new("ShaderNodeVectorTransform")
    to_obj.vector_type = "VECTOR"
    to_obj.convert_from = "WORLD"
    to_obj.convert_to = "OBJECT"
    nt.links.new(geo.outputs["Incoming"], to_obj.inputs["Vector"])
    o = nt.nodes.new("ShaderNodeCombineXYZ")
    for i, c in enumerate("XYZ"):
        o.inputs[c].default_value = float(origin_rig[i])
    rel = nt.nodes.new("ShaderNodeVectorMath")
    rel.operation = "SUBTRACT"
    nt.links.new(coord.outputs["Object"], rel.inputs[0])
    nt.links.new(o.outputs["Vector"], rel.inputs[1])
    nrel = nt.nodes.new("ShaderNodeVectorMath")
    nrel.operation = "NORMALIZE"
    nt.links.new(rel.outputs["Vector"], nrel.inputs[0])
    ninc = nt.nodes.new("ShaderNodeVectorMath")
    ninc.operation = "NORMALIZE"
    nt.links.new(to_obj.outputs["Vector"], ninc.inputs[0])
    dot = nt.nodes.new("ShaderNodeVectorMath")
    dot.operation = "DOT_PRODUCT"
    nt.links.new(nrel.outputs["Vector"], dot.inputs[0])
    nt.links.new(ninc.outputs["Vector"], dot.inputs[1])
    is_proj = nt.nodes.new("ShaderNodeMath")
    is_proj.operation = "GREATER_THAN"
    is_proj.inputs[1].default_value = 0.9999
    nt.links.new(dot.outputs["Value"], is_proj.inputs[0])
    tex = nt.nodes.new("ShaderNodeTexImage")
    tex.image = image
    tex.interpolation = "Cubic"
    tex.extension = "CLIP"
    uvn = nt.nodes.new("ShaderNodeUVMap")
    uvn.uv_map = "uv"
    nt.links.new(uvn.outputs["UV"], tex.inputs["Vector"])
    # transmission = 1 - is_proj * (1 - T)
    one_minus = nt.nodes.new("ShaderNodeMath")
    one_minus.operation = "SUBTRACT"
    one_minus.inputs[0].default_value = 1.0
    nt.links.new(tex.outputs["Color"], one_minus.inputs[1])
    block = nt.nodes.new("ShaderNodeMath")
    block.operation = "MULTIPLY"
    nt.links.new(is_proj.outputs["Value"], block.inputs[0])
    nt.links.new(one_minus.outputs["Value"], block.inputs[1])
    trans = nt.nodes.new("ShaderNodeMath")
    trans.operation = "SUBTRACT"
    trans.inputs[0].default_value = 1.0
    nt.links.new(block.outputs["Value"], trans.inputs[1])
    mix = nt.nodes.new("ShaderNodeMixShader")
    black = nt.nodes.new("ShaderNodeBsdfDiffuse")
    black.inputs["Color"].default_value = (0, 0, 0, 1)
    clear = nt.nodes.new("ShaderNodeBsdfTransparent")
    nt.links.new(trans.outputs["Value"], mix.inputs["Fac"])
    nt.links.new(black.outputs["BSDF"], mix.inputs[1])
    nt.links.new(clear.outputs["BSDF"], mix.inputs[2])
    nt.links.new(mix.outputs["Shader"], out.inputs["Surface"])
    return mat


def world_sky(rgb):
    """A sky dome brighter overhead (world -y is up): radiance rgb * (0.3 +
    0.7 max(0, up . direction))."""
    world = bpy.data.worlds.new("sky")
    bpy.context.scene.world = world
    world.use_nodes = True
    nt = world.node_tree
    bg = nt.nodes["Background"]
    coord = nt.nodes.new("ShaderNodeTexCoord")
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    nt.links.new(coord.outputs["Generated"], sep.inputs[0])
    up = nt.nodes.new("ShaderNodeMath")
    up.operation = "MULTIPLY"
    up.inputs[1].default_value = -1.0
    nt.links.new(sep.outputs["Y"], up.inputs[0])
    clampn = nt.nodes.new("ShaderNodeMath")
    clampn.operation = "MAXIMUM"
    clampn.inputs[1].default_value = 0.0
    nt.links.new(up.outputs["Value"], clampn.inputs[0])
    lin = nt.nodes.new("ShaderNodeMath")
    lin.operation = "MULTIPLY_ADD"
    lin.inputs[1].default_value = 0.7
    lin.inputs[2].default_value = 0.3
    nt.links.new(clampn.outputs["Value"], lin.inputs[0])
    gain = nt.nodes.new("ShaderNodeMath")  # 1 in the sky's pass, 0 in the others
    gain.name = "sky_gain"
    gain.operation = "MULTIPLY"
    gain.inputs[1].default_value = 1.0
    nt.links.new(lin.outputs["Value"], gain.inputs[0])
    bg.inputs["Color"].default_value = (rgb[0], rgb[1], rgb[2], 1.0)
    nt.links.new(gain.outputs["Value"], bg.inputs["Strength"])
    return world


def setup_render(cam, scene_spec, samples, threads, roi):
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    sc.cycles.device = "CPU"
    sc.cycles.samples = samples
    sc.cycles.use_adaptive_sampling = False
    sc.cycles.use_denoising = False
    sc.cycles.pixel_filter_type = "BOX"  # a pixel integrates its own square
    sc.cycles.filter_width = 1.0
    sc.cycles.max_bounces = 4
    sc.cycles.diffuse_bounces = 3
    sc.cycles.glossy_bounces = 2
    sc.cycles.transparent_max_bounces = 8
    sc.cycles.sample_clamp_direct = 0.0
    sc.cycles.sample_clamp_indirect = 0.0
    sc.render.threads_mode = "FIXED"
    sc.render.threads = threads
    sc.render.resolution_x = cam.width
    sc.render.resolution_y = cam.height
    sc.render.resolution_percentage = 100
    sc.render.pixel_aspect_x = sc.render.pixel_aspect_y = 1.0
    sc.view_settings.view_transform = "Standard"
    sc.render.film_transparent = False
    x, y, w, h = roi
    sc.render.use_border = True
    sc.render.use_crop_to_border = True
    sc.render.border_min_x = x / cam.width
    sc.render.border_max_x = (x + w) / cam.width
    sc.render.border_min_y = (cam.height - (y + h)) / cam.height  # Blender counts rows from the bottom
    sc.render.border_max_y = (cam.height - y) / cam.height
    # One render per light (pass): with one light, every light sample goes
    # to it (light groups in one render split them, Cycles 3.4 choosing a
    # light uniformly: 14 % noise in the sun's pass at 16 samples against
    # ... with its own render). The pass to a float EXR.
    sc.use_nodes = True
    nt = sc.node_tree
    for n in list(nt.nodes):
        nt.nodes.remove(n)
    rl = nt.nodes.new("CompositorNodeRLayers")
    fo = nt.nodes.new("CompositorNodeOutputFile")
    fo.format.file_format = "OPEN_EXR"  # one file per pass (OpenCV reads these, not multilayer files)
    fo.format.color_depth = "32"
    fo.format.exr_codec = "ZIP"
    nt.links.new(rl.outputs["Image"], fo.inputs[0])
    return fo


def build_camera(cam):
    data = bpy.data.cameras.new("camera")
    data.sensor_fit = "HORIZONTAL"
    data.sensor_width = cam.width * cam.pixel_m * 1e3
    data.sensor_height = cam.height * cam.pixel_m * 1e3
    data.lens = cam.focal_m * 1e3
    data.shift_x = data.shift_y = 0.0
    data.clip_start = 0.01
    data.clip_end = 100.0
    data.dof.use_dof = True
    data.dof.focus_distance = cam.focus_m
    data.dof.aperture_fstop = cam.focal_m / cam.aperture_m
    data.dof.aperture_blades = 0
    ob = bpy.data.objects.new("camera", data)
    bpy.context.scene.collection.objects.link(ob)
    bpy.context.scene.camera = ob
    return ob


def build_projector(rig, beams, sigma_rad, seed):
    light = bpy.data.lights.new("projector", "POINT")
    light.energy = 1000.0
    light.shadow_soft_size = 0.0  # a point: hard shadows of the beams
    light.color = (1.0, 1.0, 1.0)
    ob = bpy.data.objects.new("projector", light)
    bpy.context.scene.collection.objects.link(ob)
    ob.parent = rig
    ob.matrix_basis = matrix(G.iso(np.eye(3), beams[0][0]))
    mask = G.Mask(beams, sigma_rad, seed)
    img, _ = new_image("mask_t", mask.T, "Cubic")
    corners, uvs = mask.quad()
    mo = mesh_object("mask", corners, [(0, 1, 2), (0, 2, 3)], uvs)
    mo.parent = rig
    mo.data.materials.append(mask_material(img, beams[0][0]))
    for attr in ("visible_camera", "visible_diffuse", "visible_glossy", "visible_transmission",
                 "visible_volume_scatter"):
        setattr(mo, attr, False)
    mo.visible_shadow = True
    return ob, mask


def build_sun(direction, angle_rad=0.0093):
    light = bpy.data.lights.new("sun", "SUN")
    light.energy = 1.0
    light.angle = angle_rad
    ob = bpy.data.objects.new("sun", light)
    bpy.context.scene.collection.objects.link(ob)
    d = np.asarray(direction, float)
    d /= np.linalg.norm(d)
    # A sun light shines along its local -z: local +z = towards the sun.
    z = d
    x = np.cross([0.0, 1.0, 0.0], z)
    if np.linalg.norm(x) < 1e-6:
        x = np.cross([1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    ob.matrix_basis = matrix(G.iso(np.stack([x, y, z], 1), np.zeros(3)))
    return ob


def build_rock(spec, seed):
    verts, tris, uvs = G.rock_mesh(spec, seed)
    img, interp = new_image("albedo", G.rock_albedo(spec, seed), "Linear")
    ob = mesh_object("rock", verts, tris, uvs)
    ob.data.materials.append(textured_material("rock", img, interp))
    return ob, verts, tris


def build_board(spec, view, seed):
    """The board at its pose (world = reference rig frame) and a wall
    behind it."""
    img_arr, (w, h), (x0, y0), specks = G.board_print(spec, seed)
    img, interp = new_image("print", img_arr, "Closest")
    cols, rows = spec["board"]
    s = spec["square_m"]
    corners_b = [(x0, y0, 0), (x0 + w, y0, 0), (x0 + w, y0 + h, 0), (x0, y0 + h, 0)]
    # v = (y - y0) / h: image row 0 is the smallest y (geometry.board_print).
    uvs = [(0, 0), (1, 0), (1, 1), (0, 1)]
    R = G.board_pose(view)
    centre_b = np.array([(cols - 1) * s / 2, (rows - 1) * s / 2, 0.0])
    t = np.array([view.get("offset_m", [0, 0])[0], view.get("offset_m", [0, 0])[1], view["distance_m"]]) - R @ centre_b
    T = G.iso(R, t)
    verts = [tuple((T @ np.array([*c, 1.0]))[:3]) for c in corners_b]
    ob = mesh_object("board", verts, [(0, 1, 2), (0, 2, 3)], uvs)
    ob.data.materials.append(textured_material("print", img, interp, roughness=0.7, specular=0.25))
    # A wall 1 m behind the board, facing the camera.
    wd = view["distance_m"] + 1.0
    wall_v = [(-3, -3, wd), (3, -3, wd), (3, 3, wd), (-3, 3, wd)]
    wall_img = np.full((4, 4, 3), 0.3, np.float32)
    wimg, winterp = new_image("wall", wall_img, "Linear")
    wall = mesh_object("wall", wall_v, [(0, 1, 2), (0, 2, 3)], uvs)
    wall.data.materials.append(textured_material("wall", wimg, winterp))
    board_tris = np.array([[0, 1, 2], [0, 2, 3]])
    return T, np.array(verts), board_tris, specks, (np.array(wall_v), board_tris)


def beam_truth(bvh, T_world_rig, beams, cam):
    """Per beam: the hit point on the rendered mesh (world, camera frame),
    its pixel, whether the camera sees it (nothing else in between)."""
    out = []
    R, t = T_world_rig[:3, :3], T_world_rig[:3, 3]
    for o, d in beams:
        ow = R @ o + t
        dw = R @ d
        hit = bvh.ray_cast(mathutils.Vector(ow), mathutils.Vector(dw), 10.0)
        if hit[0] is None:
            out.append({"hit": False})
            continue
        pw = np.array(hit[0])
        pc = R.T @ (pw - t)
        px = cam.project(pc)
        to = pw - t
        dist = np.linalg.norm(to)
        back = bvh.ray_cast(mathutils.Vector(t), mathutils.Vector(to / dist), dist * (1 - 1e-6))
        visible = back[0] is None or np.linalg.norm(np.array(back[0]) - pw) < 1e-6
        n = np.array(hit[1])
        out.append({"hit": True, "world": pw.tolist(), "camera": pc.tolist(), "pixel": px.tolist(),
                    "visible": bool(visible), "normal_world": (n / np.linalg.norm(n)).tolist()})
    return out


def auto_roi(cam, pixels, margin):
    """The dots' bounding box plus a margin, even offsets and sizes (the
    Bayer phase of the full frame), inside the image."""
    p = np.array(pixels)
    x0 = max(0, int(math.floor(p[:, 0].min() - margin)) // 2 * 2)
    y0 = max(0, int(math.floor(p[:, 1].min() - margin)) // 2 * 2)
    x1 = min(cam.width, (int(math.ceil(p[:, 0].max() + margin)) + 1) // 2 * 2)
    y1 = min(cam.height, (int(math.ceil(p[:, 1].max() + margin)) + 1) // 2 * 2)
    return [x0, y0, x1 - x0, y1 - y0]


def main():
    a = args()
    with open(a["spec"]) as f:
        spec = yaml.safe_load(f)
    sd = next(s for s in spec["scenes"] if s["name"] == a["scene"])
    root = os.path.dirname(os.path.abspath(a["spec"]))
    cam = G.Camera(spec["camera"])
    rows, cols, beams = G.load_projector(os.path.join(root, spec["projector"]))
    out_dir = os.path.join(a["out"], sd["name"])
    os.makedirs(out_dir, exist_ok=True)
    # Start empty (run with --factory-startup: the default scene's objects go).
    for ob in list(bpy.data.objects):
        bpy.data.objects.remove(ob)
    seed = int(sd["seed"])

    rig = bpy.data.objects.new("rig", None)
    bpy.context.scene.collection.objects.link(rig)
    cam_ob = build_camera(cam)
    cam_ob.parent = rig
    cam_ob.matrix_basis = matrix(G.OPTICAL_TO_BLENDER_CAMERA)
    build_projector(rig, beams, float(sd["beam_sigma_rad"]), seed)
    build_sun(sd["sun_direction"])
    world_sky(sd.get("sky_rgb", [0.85, 1.0, 1.2]))

    truth = {"scene": sd["name"], "kind": sd["kind"], "camera": {"K": cam.K().tolist(), "width": cam.width,
             "height": cam.height}, "frames": []}
    if sd["kind"] == "rock":
        _, verts, tris = build_rock(sd["rock"], seed)
        bvh = BVHTree.FromPolygons(np.asarray(verts, float).tolist(), np.asarray(tris).tolist())  # numpy ints crash it
        motion = G.Motion(sd["motion"], float(sd["distance_m"]))
        frames = [(float(f["t"]), bool(f["projector"]), None) for f in sd["frames"]]
    else:
        frames = []
        for v in sd["views"]:
            frames.append((0.0, True, v))

    frame_sel = None if a["frames"] is None else [int(x) for x in a["frames"].split(",")]
    passes = a["passes"].split(",") if a["passes"] else sd.get("passes", ["sun", "sky", "proj"])
    samples = dict(sd.get("samples", {"sun": 64, "sky": 64, "proj": 64}))
    if a["samples"]:
        samples = {k: int(a["samples"]) for k in samples}
    fo = None
    for k, (t, proj_on, view) in enumerate(frames):
        if frame_sel is not None and k not in frame_sel:
            continue
        if view is not None:
            # A board view: a scene of its own (board pose, wall).
            for ob in [o for o in bpy.data.objects if o.name in ("board", "wall")]:
                bpy.data.objects.remove(ob)
            T_board, bverts, btris, specks, wall = build_board(sd, view, seed + k)
            allv = np.concatenate([bverts, wall[0]])
            allt = np.concatenate([btris, wall[1] + 4])
            bvh = BVHTree.FromPolygons(np.asarray(allv, float).tolist(), np.asarray(allt).tolist())
            T_world_rig = np.eye(4)
        else:
            T_world_rig = motion.world_from_rig(t)
        rig.matrix_world = matrix(T_world_rig)
        bpy.context.view_layer.update()
        bt = beam_truth(bvh, T_world_rig, beams, cam)
        entry = {"index": k, "t": t, "projector": proj_on, "T_world_camera": T_world_rig.tolist(), "beams": bt}
        if view is not None:
            entry["T_world_board"] = T_board.tolist()
            entry["specks_board"] = specks
        if a.get("roi"):
            roi = [int(v) for v in a["roi"].split(",")]
        elif "roi" in sd:
            roi = sd["roi"]
        elif view is not None:
            roi = [0, 0, cam.width, cam.height]
        else:
            # The dots at t = 0 (roi_all_frames: at every frame's time).
            times = [f[0] for f in frames] if sd.get("roi_all_frames") else [0.0]
            px = [b["pixel"] for tt in times for b in beam_truth(bvh, motion.world_from_rig(tt), beams, cam)
                  if b["hit"]]
            roi = auto_roi(cam, px, float(sd.get("roi_margin_px", 24)))
        entry["roi"] = roi
        if fo is None or view is not None:
            if fo is None:
                fo = setup_render(cam, sd, 1, int(a["threads"]), roi)
                if a["bounces"] is not None:
                    bpy.context.scene.cycles.max_bounces = int(a["bounces"])
        fo.base_path = out_dir
        bpy.context.scene.frame_current = 1
        for p, name in enumerate(("sun", "sky", "proj")):
            if (name == "proj" and not proj_on) or name not in passes:
                continue
            bpy.context.scene.cycles.seed = (seed * 1000 + k) * 3 + p + 7919 * int(a["seed_offset"])
            bpy.context.scene.cycles.samples = samples[name]
            bpy.data.objects["sun"].hide_render = name != "sun"
            bpy.data.objects["projector"].hide_render = name != "proj"
            bpy.context.scene.world.node_tree.nodes["sky_gain"].inputs[1].default_value = float(name == "sky")
            fo.file_slots[0].path = "f%d_%s_" % (k, name)  # + the frame number, 0001.exr
            bpy.ops.render.render(write_still=False)
        truth["frames"].append(entry)
        print("rendered frame %d (t = %.4f s, projector %s)" % (k, t, proj_on), flush=True)
    truth["samples"] = samples
    truth["roi_note"] = "x, y, width, height in full-frame pixels"
    with open(os.path.join(out_dir, "truth%s.json" % ("" if frame_sel is None else "_" + a["frames"].replace(",", "_"))), "w") as f:
        json.dump(truth, f)


main()
