"""`camnet match IMAGES... --rig RIG.yaml -o observations.json`: one synchronised image per camera into observations.

Each IMAGE is ``PATH``, whose camera id is the file name without its
extension (``cam0.png`` is camera ``cam0``), or ``ID=PATH``. The rig file
names the cameras and the stereo pair with its known distance; its cameras
need no driver, and their sizes come from the images. The images go through
the matcher node's engine (`camnet.matching.engine`) with the node's
options, so they give the tracks a live rig gives on its first frame set of
the same images.
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("images", nargs="+", metavar="IMAGE",
                        help="one image per camera of the rig: PATH (camera id: the file name without its "
                             "extension) or ID=PATH")
    parser.add_argument("--rig", required=True, metavar="RIG.yaml",
                        help="rig file: the cameras and the stereo pair with its known distance")
    parser.add_argument("-o", "--output", required=True, metavar="OBSERVATIONS.json",
                        help="where to write camnet.observations/1 JSON")
    parser.add_argument("--detector", choices=("sift", "orb"), default="sift",
                        help="features: sift (accurate) or orb (fast) (default: sift)")
    parser.add_argument("--max-features", type=int, default=4000, metavar="N",
                        help="features per image (default: 4000)")
    parser.add_argument("--max-image-side-px", type=int, metavar="PX",
                        help="detect on a downscaled copy of larger images; pixels stay full size (default: full size)")
    parser.add_argument("--normalise-contrast", action=argparse.BooleanOptionalAction, default=True,
                        help="stretch and equalise (CLAHE) each image before detection (default: True)")


def image_paths(arguments: list[str], camera_ids: list[str]) -> dict[str, str]:
    """Camera id -> image path, one per camera of the rig; InputError naming what is wrong."""
    from pathlib import Path

    from camnet.errors import InputError

    paths: dict[str, str] = {}
    for argument in arguments:
        camera_id, sep, path = argument.partition("=")
        if not sep or camera_id not in camera_ids:
            camera_id, path = Path(argument).stem, argument
        if camera_id not in camera_ids:
            raise InputError(f"{argument}: no camera {camera_id!r} in the rig (cameras: {', '.join(camera_ids)}); "
                             "name the file after its camera or write ID=PATH")
        if camera_id in paths:
            raise InputError(f"{argument}: a second image for camera {camera_id!r} (also {paths[camera_id]})")
        paths[camera_id] = path
    missing = [c for c in camera_ids if c not in paths]
    if missing:
        raise InputError(f"no image for camera{'s' if len(missing) > 1 else ''} {', '.join(missing)}: "
                         f"give one image per camera of the rig ({len(camera_ids)}), {len(paths)} given")
    return paths


def read_image(path: str, expected_size: tuple[int, int] | None):
    """The image at `path` as stored (grey or colour, 8 or 16 bits); InputError if it cannot be used."""
    from pathlib import Path

    import cv2

    from camnet.errors import InputError

    if not Path(path).is_file():
        raise InputError(f"{path}: no such image file")
    image = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InputError(f"{path}: cannot be read as an image (OpenCV knows PNG, JPEG, TIFF, PGM, ...)")
    size = (image.shape[1], image.shape[0])
    if expected_size is not None and size != expected_size:
        raise InputError(f"{path}: {size[0]}x{size[1]} pixels, but the rig file says "
                         f"{expected_size[0]}x{expected_size[1]}")
    return image


def run(args: argparse.Namespace) -> int:
    import json
    import sys

    import numpy as np

    from camnet.errors import InputError
    from camnet.io.formats import observations_to_doc, write_json_atomic
    from camnet.io.rig import camera_info, configured_size, load_rig
    from camnet.matching.features import Detector
    from camnet.matching.pipeline import observations_from_frame_sets
    from camnet.services.matcher import MatcherNodeConfig, rig_stereo

    rig = load_rig(args.rig)
    stereo = rig_stereo(rig)
    if args.max_features < 1:
        raise InputError(f"--max-features: must be at least 1, got {args.max_features}")
    if args.max_image_side_px is not None and args.max_image_side_px < 16:
        raise InputError(f"--max-image-side-px: must be at least 16, got {args.max_image_side_px}")
    camera_ids = [c.id for c in rig.cameras]
    paths = image_paths(args.images, camera_ids)
    images = {c: read_image(paths[c], configured_size(rig, c)) for c in camera_ids}
    cameras = [camera_info(rig, c, images[c].shape[1], images[c].shape[0]) for c in camera_ids]
    # The matcher node's engine with the node's options: these images give the tracks the live rig's would.
    config = MatcherNodeConfig(detector=Detector(args.detector), max_features=args.max_features,
                               max_image_side_px=args.max_image_side_px, normalise_contrast=args.normalise_contrast)
    obs = observations_from_frame_sets([images], cameras=cameras, stereo=stereo, config=config.engine_config())
    if len(obs.track_ids) == 0:
        raise InputError("no tracks: no two images share verified matches (see the warnings above); "
                         "are these images of one scene, taken at one instant?")
    write_json_atomic(args.output, observations_to_doc(obs))
    seen = np.bincount(obs.cam_index, minlength=len(cameras))
    summary = {"output": args.output, "tracks": len(obs.track_ids),
               "observations": {c.id: int(n) for c, n in zip(cameras, seen, strict=True)}}
    print(json.dumps(summary), file=sys.stdout)
    unseen = [c.id for c, n in zip(cameras, seen, strict=True) if n == 0]
    if unseen:
        print(f"camnet match: warning: no track reaches camera {', '.join(unseen)}; it cannot be calibrated",
              file=sys.stderr)
    return 0
