#!/usr/bin/env python3
"""COLMAP as a second judge of a capture directory (issue 12).

Runs pycolmap on the images a capture directory's transforms.json names: SIFT
extraction with the known intrinsics (one shared PINHOLE camera), sequential
matching and incremental mapping, all on the CPU with at most two threads. It
then compares the reconstruction with the poses of transforms.json after a
similarity transform (Umeyama, on the registered images): camera centres, and
each image's rotation against transforms.json's and against geo.txt's (ODM's
yaw, pitch, roll) when the directory has one; given sample points on occluded
surfaces, it says how many carry a triangulated point nearby.

    scripts/colmap_judge.py CAPTURE_DIR [--work DIR] [--occluded-points FILE]
                            [--tolerance-m T] [--json OUT] [--refine-focal]

transforms.json is nerfstudio's (docs/capture-log.md): fl_x fl_y cx cy w h,
frames[].file_path and frames[].transform_matrix, camera-to-world with the
camera in OpenGL axes (x right, y up, z back) and the world in local ENU metres.
The occluded points file is {"points_m": [[x, y, z], ...]} in the same frame.
geo.txt is OpenDroneMap's (`EPSG:4326`, then `image lon lat alt yaw pitch roll`,
degrees): the rotation is ODM's, Rz(yaw) Ry(pitch) Rx(roll) times its camera to
body axes (`opendm/photo.py` compute_opk), NED, turned into ENU here.

Exit 0 when it ran (also when few images register: the figures say so), 2 with
one line on stderr for bad input, 1 if pycolmap itself fails.

The --json object: images_total, images_registered, registered_fraction,
models (how many the mapper made; model_used is the largest), mean_reprojection_px,
points3d, intrinsics {given, final, focal_refined}, track_length_m (the way
flown: the centres' consecutive distances, capture order), similarity {scale, rotation, translation_m, roll_about_track_from},
centre_error_m / centre_error_fraction / rotation_error_deg (against
transforms.json) / geo_rotation_error_deg (against geo.txt; null without one)
{median, max} over the registered images, geo_images (images with angles in
geo.txt), completeness {points, tolerance_m, covered, fraction} (null without
--occluded-points; 0 covered when nothing was reconstructed), per_image [{image,
registered, centre_error_m, rotation_error_deg, geo_rotation_error_deg}], seconds.
A figure that cannot be computed is null.
"""

import argparse
import json
import math
import os
import shutil
import sys
import tempfile
import time

THREADS = 2
SEED = 0
# Sequential matching pairs each image with this many following ones (plus
# quadratic ones further out): a flight's neighbours overlap by far more.
OVERLAP = 10
# Frames with fewer pixels are upsampled for SIFT (see run()).
SMALL_FRAME_PX = 640 * 480
# Centres whose lateral spread is under this fraction of their length are a line.
COLLINEAR = 0.02


class BadInput(Exception):
    pass


def load_transforms(capture_dir):
    path = os.path.join(capture_dir, "transforms.json")
    if not os.path.isfile(path):
        raise BadInput(f"{path}: no such file (is {capture_dir} a capture directory?)")
    try:
        with open(path) as f:
            t = json.load(f)
    except (OSError, ValueError) as e:
        raise BadInput(f"{path}: not readable JSON: {e}")
    try:
        intr = {k: float(t[k]) for k in ("fl_x", "fl_y", "cx", "cy")}
        intr["w"], intr["h"] = int(t["w"]), int(t["h"])
        frames = t["frames"]
    except (KeyError, TypeError, ValueError) as e:
        raise BadInput(f"{path}: missing or malformed intrinsics or frames: {e}")
    names, c2w = [], []
    for i, fr in enumerate(frames):
        try:
            name = fr["file_path"]
            m = [[float(v) for v in row] for row in fr["transform_matrix"]]
        except (KeyError, TypeError, ValueError) as e:
            raise BadInput(f"{path}: frames[{i}]: malformed: {e}")
        if len(m) < 3 or any(len(r) != 4 for r in m[:3]):
            raise BadInput(f"{path}: frames[{i}]: transform_matrix is not 4x4")
        for k in ("fl_x", "fl_y", "cx", "cy", "w", "h"):
            if k in fr and float(fr[k]) != float(intr[k]):
                raise BadInput(
                    f"{path}: frames[{i}] has its own {k}; only one shared camera is supported"
                )
        if os.path.isabs(name) or not os.path.isfile(os.path.join(capture_dir, name)):
            raise BadInput(f"{path}: frames[{i}]: image {name!r} not found in {capture_dir}")
        names.append(os.path.normpath(name))
        c2w.append(m)
    if not names:
        raise BadInput(f"{path}: no frames, so no images to reconstruct")
    return intr, names, c2w


def load_geo(capture_dir):
    """{image: (yaw, pitch, roll) degrees} of geo.txt's lines with angles; None without the file."""
    path = os.path.join(capture_dir, "geo.txt")
    if not os.path.isfile(path):
        return None
    angles = {}
    with open(path) as f:
        lines = f.read().splitlines()
    if not lines or lines[0].strip() != "EPSG:4326":
        raise BadInput(f"{path}: the first line is not EPSG:4326")
    for k, line in enumerate(lines[1:], start=2):
        fields = line.split()
        if len(fields) < 7:
            continue  # position only: no attitude to judge
        try:
            angles[os.path.normpath(fields[0])] = tuple(float(v) for v in fields[4:7])
        except ValueError as e:
            raise BadInput(f"{path}: line {k}: {e}")
    return angles


def odm_rotation(yaw_deg, pitch_deg, roll_deg, np):
    """Camera (OpenCV axes) to world (ENU) from geo.txt's angles, as ODM reads them."""
    def rz(a):
        c, s = math.cos(a), math.sin(a)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    def ry(a):
        c, s = math.cos(a), math.sin(a)
        return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])

    def rx(a):
        c, s = math.cos(a), math.sin(a)
        return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])

    # ODM's image axes (x right, y up = top of the image, z back) to its body (FRD);
    # the same swap takes NED to ENU.
    swap = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    cnb = rz(math.radians(yaw_deg)) @ ry(math.radians(pitch_deg)) @ rx(math.radians(roll_deg))
    return swap @ cnb @ swap @ np.diag([1.0, -1.0, -1.0])


def load_points(path):
    try:
        with open(path) as f:
            pts = json.load(f)["points_m"]
        return [[float(p[0]), float(p[1]), float(p[2])] for p in pts]
    except (OSError, ValueError, KeyError, TypeError, IndexError) as e:
        raise BadInput(f"{path}: expected {{\"points_m\": [[x, y, z], ...]}}: {e}")


def umeyama(src, dst, np):
    """s, R, t minimising sum |dst - (s R src + t)|^2 (Umeyama 1991); src, dst n x 3."""
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    var_s = (xs ** 2).sum() / len(src)
    cov = xd.T @ xs / len(src)
    u, d, vt = np.linalg.svd(cov)
    e = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        e[2, 2] = -1.0
    r = u @ e @ vt
    s = float(np.trace(np.diag(d) @ e) / var_s) if var_s > 0 else float("nan")
    return s, r, mu_d - s * r @ mu_s


def axis_rotation(u, theta, np):
    """Rotation by theta (radians) about the unit axis u (Rodrigues)."""
    k = np.array([[0.0, -u[2], u[1]], [u[2], 0.0, -u[0]], [-u[1], u[0], 0.0]])
    return np.eye(3) + math.sin(theta) * k + (1.0 - math.cos(theta)) * (k @ k)


def similarity(est_c, truth_c, est_r, truth_r, np):
    """World from COLMAP: scale, rotation and translation from the camera centres (Umeyama).

    A survey line is straight: its centres fix the scale, the translation and the
    line's direction, but not the roll about the line. When the centres are that
    close to collinear (lateral spread under COLLINEAR of their length), the roll
    is taken from the camera orientations instead: the angle about the line, through
    the centres' mean, that best aligns them, fitted robustly (a grid search on the
    lower quartile of the angles, then least squares on the images within twice
    it, repeated), so that images whose logged attitude is wrong do not drag it
    as long as a quarter are right.
    The rotation errors then measure the orientations relative to each other,
    not their common roll.
    """
    s, r, t = umeyama(est_c, truth_c, np)
    centred = truth_c - truth_c.mean(0)
    _, sv, vt = np.linalg.svd(centred, full_matrices=False)
    if sv[0] <= 0 or sv[1] / sv[0] >= COLLINEAR:
        return {"scale": s, "r": r, "t": t, "roll_from": "centres"}
    u = vt[0]
    a = [r @ w for w in est_r]  # COLMAP orientations in the world, before the roll

    def errors(theta):
        q = axis_rotation(u, theta, np)
        return [rotation_angle_deg(tr.T @ (q @ ai), np) for tr, ai in zip(truth_r, a)]

    k = np.array([[0.0, -u[2], u[1]], [u[2], 0.0, -u[0]], [-u[1], u[0], 0.0]])
    grid = [math.radians(d) for d in np.arange(-180.0, 180.0, 1.0)]
    theta = min(grid, key=lambda th: lower_quartile(errors(th)))
    for _ in range(4):
        # Least squares about u on the images that agree best, i.e. maximise
        # sum trace(T_i^T Q(theta) A_i) = trace(Q(theta) M): closed form.
        e = errors(theta)
        limit = 2.0 * lower_quartile(e) + 1e-3
        m = sum(ai @ tr.T for ai, tr, ei in zip(a, truth_r, e) if ei <= limit)
        theta = math.atan2(float(np.trace(k @ m)), float(np.trace(m) - u @ m @ u))
    q = axis_rotation(u, theta, np)
    mean = truth_c.mean(0)
    return {"scale": s, "r": q @ r, "t": q @ (t - mean) + mean, "roll_from": "orientations (centres collinear)"}


def rotation_angle_deg(r, np):
    c = (np.trace(r) - 1.0) / 2.0
    return math.degrees(math.acos(max(-1.0, min(1.0, float(c)))))


def lower_quartile(values):
    v = sorted(values)
    return v[(len(v) - 1) // 4]


def stats(values):
    if not values:
        return {"median": None, "max": None}
    v = sorted(values)
    n = len(v)
    med = v[n // 2] if n % 2 else 0.5 * (v[n // 2 - 1] + v[n // 2])
    return {"median": med, "max": v[-1]}


def nearest_within(queries, points, tol, np):
    """How many queries have a point within tol (brute force in chunks: no scipy)."""
    if len(points) == 0 or len(queries) == 0:
        return 0
    hit = 0
    pts = points.astype(np.float64)
    p2 = (pts ** 2).sum(1)
    for i in range(0, len(queries), 512):
        q = queries[i : i + 512]
        d2 = (q ** 2).sum(1)[:, None] + p2[None, :] - 2.0 * q @ pts.T
        hit += int((d2.min(1) <= tol * tol).sum())
    return hit


def run(args):
    import numpy as np
    import pycolmap

    capture_dir = os.path.abspath(args.capture_dir)
    intr, names, c2w = load_transforms(capture_dir)
    geo = load_geo(capture_dir)
    occluded = load_points(args.occluded_points) if args.occluded_points else None

    pycolmap.logging.minloglevel = 2  # warnings and errors only
    pycolmap.set_random_seed(SEED)
    t0 = time.monotonic()

    own_work = args.work is None
    work = tempfile.mkdtemp(prefix="colmap_judge.") if own_work else os.path.abspath(args.work)
    try:
        os.makedirs(work, exist_ok=True)
        db = os.path.join(work, "database.db")
        sparse = os.path.join(work, "sparse")
        # A fresh database each run: COLMAP would otherwise skip images it has.
        if os.path.exists(db):
            os.remove(db)
        shutil.rmtree(sparse, ignore_errors=True)
        os.makedirs(sparse)

        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = "PINHOLE"
        reader.camera_params = "{fl_x!r},{fl_y!r},{cx!r},{cy!r}".format(**intr)
        extraction = pycolmap.FeatureExtractionOptions()
        extraction.num_threads = THREADS
        extraction.use_gpu = False
        # SIFT's default upsamples the image first (octave -1): 10x the work, and
        # needed only for small frames (the eval's are 200 x 150) to find enough
        # features; from 640 x 480 up the native octave finds plenty.
        extraction.sift.first_octave = -1 if intr["w"] * intr["h"] < SMALL_FRAME_PX else 0
        # Images enter the database one by one in transforms.json's order first, so
        # their ids do not depend on which extraction thread finishes first.
        pycolmap.Database.open(db).close()  # import_images wants the file to exist
        pycolmap.import_images(
            db,
            capture_dir,
            camera_mode=pycolmap.CameraMode.SINGLE,
            image_names=names,
            options=reader,
        )
        pycolmap.extract_features(
            db,
            capture_dir,
            image_names=names,
            camera_mode=pycolmap.CameraMode.SINGLE,
            reader_options=reader,
            extraction_options=extraction,
            device=pycolmap.Device.cpu,
        )
        t_extract = time.monotonic()

        # One matching thread: with two, a few pairs came out differently from run
        # to run (COLMAP's per-thread random generators), and it was no slower here.
        pycolmap.set_random_seed(SEED)
        matching = pycolmap.FeatureMatchingOptions()
        matching.num_threads = 1
        matching.use_gpu = False
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = OVERLAP
        pairing.quadratic_overlap = True
        pairing.num_threads = 1
        verification = pycolmap.TwoViewGeometryOptions()
        verification.ransac.random_seed = SEED
        pycolmap.match_sequential(
            db,
            matching_options=matching,
            pairing_options=pairing,
            verification_options=verification,
            device=pycolmap.Device.cpu,
        )
        t_match = time.monotonic()

        pycolmap.set_random_seed(SEED)
        mapping = pycolmap.IncrementalPipelineOptions()
        mapping.num_threads = 1  # one thread: the same model on every run
        mapping.random_seed = SEED
        mapping.mapper.random_seed = SEED
        mapping.mapper.num_threads = 1
        mapping.triangulation.random_seed = SEED
        refine = bool(args.refine_focal)
        mapping.ba_refine_focal_length = refine
        mapping.ba_refine_principal_point = False
        mapping.ba_refine_extra_params = False
        mapping.mapper.abs_pose_refine_focal_length = refine
        mapping.mapper.abs_pose_refine_extra_params = False
        models = pycolmap.incremental_mapping(db, capture_dir, sparse, mapping)
        t_map = time.monotonic()

        report = {
            "capture_dir": capture_dir,
            "pycolmap_version": pycolmap.__version__,
            "images_total": len(names),
            "images_registered": 0,
            "registered_fraction": 0.0,
            "models": len(models),
            "model_used": None,
            "mean_reprojection_px": None,
            "points3d": 0,
            "intrinsics": {
                "model": "PINHOLE",
                "given": {k: intr[k] for k in ("fl_x", "fl_y", "cx", "cy")},
                "focal_refined": refine,
                "final": None,
            },
            "track_length_m": None,
            "similarity": None,
            "centre_error_m": stats([]),
            "centre_error_fraction": stats([]),
            "rotation_error_deg": stats([]),
            "geo_rotation_error_deg": stats([]),
            "geo_images": None if geo is None else sum(n in geo for n in names),
            "completeness": None,
            "per_image": [],
            "seconds": {},
        }
        truth_c = np.array([[m[0][3], m[1][3], m[2][3]] for m in c2w])
        # OpenGL camera axes (x right, y up, z back) to COLMAP's OpenCV (x right, y down, z forward).
        flip = np.diag([1.0, -1.0, -1.0])
        truth_r = [np.array([row[:3] for row in m[:3]]) @ flip for m in c2w]
        geo_r = [odm_rotation(*geo[n], np) if geo and n in geo else None for n in names]
        # The way flown, not first to last: over lanes flown back and forth the
        # two ends are close. On one straight line the two agree.
        report["track_length_m"] = float(np.linalg.norm(np.diff(truth_c, axis=0), axis=1).sum())

        by_name, per = {}, {}  # registered images by name; their errors by index
        if models:
            key = max(models, key=lambda k: (models[k].num_reg_images(), models[k].num_points3D(), -k))
            rec = models[key]
            report["model_used"] = int(key)
            report["images_registered"] = rec.num_reg_images()
            report["registered_fraction"] = rec.num_reg_images() / len(names)
            report["mean_reprojection_px"] = float(rec.compute_mean_reprojection_error())
            report["points3d"] = rec.num_points3D()
            cam = next(iter(rec.cameras.values()))
            report["intrinsics"]["final"] = dict(
                zip(("fl_x", "fl_y", "cx", "cy"), (float(p) for p in cam.params))
            )
            by_name = {img.name: img for img in rec.images.values() if img.has_pose}
            reg = [i for i, n in enumerate(names) if n in by_name]
            est_c = np.array([by_name[names[i]].projection_center() for i in reg]).reshape(-1, 3)
            if len(reg) >= 3:
                world_from_cam = [by_name[names[i]].cam_from_world().rotation.matrix().T for i in reg]
                sim = similarity(est_c, truth_c[reg], world_from_cam, [truth_r[i] for i in reg], np)
                s, r, t = sim["scale"], sim["r"], sim["t"]
                report["similarity"] = {
                    "scale": s,
                    "rotation": r.tolist(),
                    "translation_m": t.tolist(),
                    "roll_about_track_from": sim["roll_from"],
                }
                aligned = (s * (r @ est_c.T)).T + t
                errs = np.linalg.norm(aligned - truth_c[reg], axis=1)
                rot_errs = [
                    rotation_angle_deg(truth_r[i].T @ (r @ w), np) for i, w in zip(reg, world_from_cam)
                ]
                length = report["track_length_m"]
                report["centre_error_m"] = stats([float(e) for e in errs])
                report["centre_error_fraction"] = stats(
                    [float(e) / length for e in errs] if length > 0 else []
                )
                report["rotation_error_deg"] = stats(rot_errs)
                geo_errs = {
                    i: rotation_angle_deg(geo_r[i].T @ (r @ w), np)
                    for i, w in zip(reg, world_from_cam)
                    if geo_r[i] is not None
                }
                if geo is not None:
                    report["geo_rotation_error_deg"] = stats(list(geo_errs.values()))
                per = {i: (float(errs[j]), rot_errs[j], geo_errs.get(i)) for j, i in enumerate(reg)}
            if occluded is not None:
                comp = {
                    "points": len(occluded),
                    "tolerance_m": args.tolerance_m,
                    "covered": None,
                    "fraction": None,
                }
                if report["similarity"] is not None:
                    xyz = np.array([p.xyz for p in rec.points3D.values()]).reshape(-1, 3)
                    world = (s * (r @ xyz.T)).T + t
                    covered = nearest_within(np.array(occluded).reshape(-1, 3), world, args.tolerance_m, np)
                    comp["covered"] = covered
                    comp["fraction"] = covered / len(occluded) if occluded else None
                report["completeness"] = comp
        elif occluded is not None:
            # No model, no triangulated point: nothing is covered.
            report["completeness"] = {
                "points": len(occluded),
                "tolerance_m": args.tolerance_m,
                "covered": 0,
                "fraction": 0.0 if occluded else None,
            }
        for i, n in enumerate(names):
            report["per_image"].append(
                {
                    "image": n,
                    "registered": n in by_name,
                    "centre_error_m": per[i][0] if i in per else None,
                    "rotation_error_deg": per[i][1] if i in per else None,
                    "geo_rotation_error_deg": per[i][2] if i in per else None,
                }
            )
        report["seconds"] = {
            "extraction": round(t_extract - t0, 3),
            "matching": round(t_match - t_extract, 3),
            "mapping": round(t_map - t_match, 3),
            "total": round(time.monotonic() - t0, 3),
        }
        return report
    finally:
        if own_work:
            shutil.rmtree(work, ignore_errors=True)


def finite_or_none(v):
    """JSON has no NaN: a non-finite figure is written as null (as the manifest does)."""
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, dict):
        return {k: finite_or_none(x) for k, x in v.items()}
    if isinstance(v, list):
        return [finite_or_none(x) for x in v]
    return v


def fmt(v, spec):
    return "–" if v is None else format(v, spec)


def print_table(r, out):
    def row(k, v):
        print(f"{k:<28} {v}", file=out)

    row("images registered", f"{r['images_registered']} / {r['images_total']}")
    if r["models"] > 1:
        row("models", f"{r['models']} (the largest, #{r['model_used']}, is judged)")
    row("mean reprojection (px)", fmt(r["mean_reprojection_px"], ".3f"))
    row("3-D points", r["points3d"])
    fin = r["intrinsics"]["final"]
    if fin is not None:
        row(
            "focal (px) given / final",
            f"{r['intrinsics']['given']['fl_x']:.2f} / {fin['fl_x']:.2f}"
            + (" (refined)" if r["intrinsics"]["focal_refined"] else " (held fixed)"),
        )
    row("track length (m)", fmt(r["track_length_m"], ".2f"))
    if r["similarity"] is not None:
        row("similarity scale", f"{r['similarity']['scale']:.4f}")
    ce, cf, re_ = r["centre_error_m"], r["centre_error_fraction"], r["rotation_error_deg"]
    row(
        "centre error median / max",
        f"{fmt(ce['median'], '.3f')} / {fmt(ce['max'], '.3f')} m"
        f"  ({fmt(cf['median'] and 100 * cf['median'], '.2f')} / {fmt(cf['max'] and 100 * cf['max'], '.2f')} % of track)",
    )
    row("rotation error median / max", f"{fmt(re_['median'], '.2f')} / {fmt(re_['max'], '.2f')} deg")
    if r["geo_images"] is not None:
        ge = r["geo_rotation_error_deg"]
        row(
            "geo.txt rotation med / max",
            f"{fmt(ge['median'], '.2f')} / {fmt(ge['max'], '.2f')} deg ({r['geo_images']} images with angles)",
        )
    c = r["completeness"]
    if c is not None:
        row(
            "completeness",
            f"{fmt(c['fraction'], '.3f')} ({c['covered']} of {c['points']} occluded points"
            f" within {c['tolerance_m']} m)",
        )
    s = r["seconds"]
    row(
        "time (s)",
        f"{s['total']:.1f} (extraction {s['extraction']:.1f}, matching {s['matching']:.1f},"
        f" mapping {s['mapping']:.1f})",
    )


def main(argv=None):
    p = argparse.ArgumentParser(
        description="Run COLMAP (pycolmap, CPU) on a capture directory and judge it against its transforms.json."
    )
    p.add_argument("capture_dir", help="directory with transforms.json and the images it names")
    p.add_argument("--work", help="keep COLMAP's database and model here (default: a temporary directory)")
    p.add_argument("--occluded-points", help='JSON {"points_m": [[x, y, z], ...]}, local ENU metres')
    p.add_argument("--tolerance-m", type=float, default=0.5, help="completeness radius (default 0.5 m)")
    p.add_argument("--json", help="also write the figures as one JSON object here")
    p.add_argument(
        "--refine-focal",
        action="store_true",
        help="let bundle adjustment refine the focal length (default: held at transforms.json's)",
    )
    args = p.parse_args(argv)
    if not (args.tolerance_m > 0 and math.isfinite(args.tolerance_m)):
        print(f"colmap_judge: --tolerance-m must be positive, got {args.tolerance_m}", file=sys.stderr)
        return 2
    try:
        import pycolmap  # noqa: F401
    except ImportError:
        print("colmap_judge: pycolmap is missing: pip install pycolmap, or run scripts/setup.sh", file=sys.stderr)
        return 2
    try:
        report = finite_or_none(run(args))
    except BadInput as e:
        print(f"colmap_judge: {e}", file=sys.stderr)
        return 2
    print_table(report, sys.stdout)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(report, f, indent=1, allow_nan=False)
            f.write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
