#!/usr/bin/env python3
"""COLMAP's reconstruction from known poses on a flight directory's own model.

alfd writes a COLMAP text model beside its images (cameras.txt, images.txt,
points3D.txt: docs/capture-log.md): the intrinsics and the pose of every
image as logged, and no point. This runs what a reconstruction engineer runs
on it, with pycolmap on the CPU: SIFT extraction with the model's camera,
sequential matching, then point triangulation with the poses held fixed
(`colmap point_triangulator`). Poses that disagree with the images leave few
points, or points whose reprojection error is large; the figures say which.

    scripts/colmap_known_poses.py FLIGHT_DIR [--work DIR] [--json OUT]

The --json object: images (in the model), images_with_points (images that
observe a triangulated point), points3d, mean_reprojection_px, mean_track_length,
point_z_m {min, median, max} (the points' heights in the model's ENU metres),
seconds. A figure that cannot be computed is null.

Exit 0 when it ran, 2 with one line on stderr for bad input, 1 if pycolmap
itself fails.
"""

import argparse
import json
import os
import shutil
import statistics
import sys
import tempfile
import time

THREADS = 2
SEED = 0
# Sequential matching pairs each image with this many following ones.
OVERLAP = 10


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("flight_dir")
    ap.add_argument("--work", help="where the database and the model go (default: a temporary directory)")
    ap.add_argument("--json", help="write the figures here")
    args = ap.parse_args()
    flight = os.path.abspath(args.flight_dir)
    for name in ("cameras.txt", "images.txt", "points3D.txt"):
        if not os.path.isfile(os.path.join(flight, name)):
            print(f"{flight}: no {name}: not a flight directory with alfd's COLMAP model", file=sys.stderr)
            return 2
    try:
        import pycolmap
    except ImportError:
        print("pycolmap is not installed (pip install pycolmap)", file=sys.stderr)
        return 2

    pycolmap.logging.minloglevel = 2
    pycolmap.set_random_seed(SEED)
    t0 = time.monotonic()
    model = pycolmap.Reconstruction(flight)
    names = [model.images[i].name for i in sorted(model.images)]
    cameras = {c.camera_id: c for c in model.cameras.values()}
    if len(cameras) != 1:
        print(f"{flight}: {len(cameras)} cameras in the model; this judge takes one", file=sys.stderr)
        return 2
    camera = next(iter(cameras.values()))

    own_work = args.work is None
    work = tempfile.mkdtemp(prefix="colmap_known.") if own_work else os.path.abspath(args.work)
    try:
        os.makedirs(work, exist_ok=True)
        db = os.path.join(work, "database.db")
        out = os.path.join(work, "triangulated")
        if os.path.exists(db):
            os.remove(db)
        shutil.rmtree(out, ignore_errors=True)
        os.makedirs(out)

        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = "PINHOLE"
        reader.camera_params = ",".join(repr(float(p)) for p in camera.params)
        extraction = pycolmap.FeatureExtractionOptions()
        extraction.num_threads = THREADS
        extraction.use_gpu = False
        extraction.sift.first_octave = 0
        pycolmap.Database.open(db).close()
        pycolmap.import_images(
            db, flight, camera_mode=pycolmap.CameraMode.SINGLE, image_names=names, options=reader
        )
        pycolmap.extract_features(
            db,
            flight,
            image_names=names,
            camera_mode=pycolmap.CameraMode.SINGLE,
            reader_options=reader,
            extraction_options=extraction,
            device=pycolmap.Device.cpu,
        )
        pycolmap.set_random_seed(SEED)
        matching = pycolmap.FeatureMatchingOptions()
        matching.num_threads = 1
        matching.use_gpu = False
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = OVERLAP
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

        # The database numbers images in import order; the model numbers them in
        # capture order, the same order here: the ids agree, and so do the names.
        with pycolmap.Database.open(db) as d:
            by_name = {im.name: im.image_id for im in d.read_all_images()}
        for image in model.images.values():
            if by_name.get(image.name) != image.image_id:
                print(f"{image.name}: id {image.image_id} in the model, {by_name.get(image.name)} in the database", file=sys.stderr)
                return 2

        pycolmap.set_random_seed(SEED)
        options = pycolmap.IncrementalPipelineOptions()
        options.num_threads = 1
        options.random_seed = SEED
        options.triangulation.random_seed = SEED
        rec = pycolmap.triangulate_points(model, db, flight, out, options=options)

        points = list(rec.points3D.values())
        seen = set()
        for p in points:
            for el in p.track.elements:
                seen.add(el.image_id)
        zs = sorted(p.xyz[2] for p in points)
        report = {
            "flight_dir": flight,
            "pycolmap_version": pycolmap.__version__,
            "images": len(names),
            "images_with_points": len(seen),
            "points3d": len(points),
            "mean_reprojection_px": rec.compute_mean_reprojection_error() if points else None,
            "mean_track_length": (sum(p.track.length() for p in points) / len(points)) if points else None,
            "point_z_m": {"min": zs[0], "median": statistics.median(zs), "max": zs[-1]} if zs else None,
            "seconds": time.monotonic() - t0,
        }
    finally:
        if own_work:
            shutil.rmtree(work, ignore_errors=True)

    text = json.dumps(report, indent=2)
    print(text)
    if args.json:
        with open(args.json, "w") as f:
            f.write(text + "\n")
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except Exception as e:  # pycolmap's own failure
        print(f"colmap_known_poses: {type(e).__name__}: {e}", file=sys.stderr)
        sys.exit(1)
