"""`camnet init`: write a rig file of the cameras this host sees, with the stereo pair and its baseline.

It asks which two cameras form the pair and how far apart their centres
are, a length with its unit (``120 mm``, ``0.12 m``, ``12 cm``); `--pair`
and `--baseline` answer without asking. The file is checked by camnet's rig
loader before it is written, and an existing file is replaced only with
`--force`.

With `--images DIR` the cameras are those of a folder of images
(camnet.io.image_folders): one v4l2 image sequence per subfolder, for
`camnet up`, or one camera per image file, for `camnet match`; their sizes
are read from the images. It asks nothing: what `--pair` and `--baseline`
do not give is written as a stereo line marked FILL IN, commented out, so
that the rig loads but no calibration runs until the distance is measured.
"""

from __future__ import annotations

import argparse
import re
from operator import attrgetter
from pathlib import Path

_LENGTH = re.compile(r"\s*([0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE]([-+]?[0-9]+))?\s*([a-zA-Z]*)\s*")
UNITS_M = {"mm": 1e-3, "cm": 1e-2, "m": 1.0}
EXAMPLES = "120 mm, 0.12 m or 12 cm"
HEADER = """\
# Written by camnet init from the cameras found. stereo.baseline_m is the distance between the pair's
# camera centres. Set stereo.parallel: true for a parallel head (side by side, looking the same way);
# a camera's settings (size, frame rate, exposure) and known intrinsics: config/README.md.
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from camnet.commands.cameras import add_discovery_arguments

    parser.add_argument("-o", "--output", default="rig.yaml", metavar="RIG.yaml",
                        help="the rig file to write (default: rig.yaml)")
    parser.add_argument("--force", action="store_true", help="replace the rig file if it exists")
    parser.add_argument("--pair", nargs=2, metavar=("LEFT", "RIGHT"),
                        help="the stereo pair: two camera ids (or numbers) as `camnet cameras` lists them; "
                             "asked when not given (with --images: left to fill in)")
    parser.add_argument("--baseline", metavar="LENGTH",
                        help=f"the distance between the pair's centres, with its unit: {EXAMPLES}; "
                             "asked when not given (with --images: left to fill in)")
    parser.add_argument("--name", help="the rig's name (default: the file's name, e.g. rig)")
    parser.add_argument("--images", metavar="DIR",
                        help="the cameras of a folder of images instead of those found: one subfolder of frames per "
                             "camera (an image sequence, with its timestamps.txt if it has one; KITTI's layout "
                             "too), or one image per camera (for camnet match); sizes are read from the images. "
                             "What --pair and --baseline do not give is left to fill in, marked FILL IN")
    add_discovery_arguments(parser)


def parse_length_m(text: str) -> float:
    """A length with its unit (mm, cm, m) in metres; ValueError saying what is wrong (a bare number too)."""
    match = _LENGTH.fullmatch(text)
    if match is None:
        raise ValueError(f"{text!r} is not a length; give it with its unit: {EXAMPLES}")
    value = float(match[1] + (f"e{match[2]}" if match[2] else ""))
    unit = match[3].lower()
    if not unit:
        raise ValueError(f"{text!r} has no unit; give it with one: {EXAMPLES}")
    if unit not in UNITS_M:
        raise ValueError(f"{text!r}: unknown unit {match[3]!r}; use mm, cm or m: {EXAMPLES}")
    if not value > 0:
        raise ValueError(f"{text!r}: a baseline must be longer than zero")
    return value * UNITS_M[unit]


def pick_pair(words: list[str], cameras, *, id_of=attrgetter("suggested_id")) -> tuple:
    """The two cameras `words` name (ids, `id_of` each camera, or 1-based numbers); ValueError naming what is
    wrong."""
    ids = [id_of(c) for c in cameras]
    if len(words) != 2:
        raise ValueError(f"name two cameras, left then right (ids: {', '.join(ids)})")
    pair = []
    for word in words:
        if word.isdigit() and 1 <= int(word) <= len(cameras):
            pair.append(cameras[int(word) - 1])
        elif word in ids:
            pair.append(cameras[ids.index(word)])
        else:
            raise ValueError(f"no camera {word!r} (ids: {', '.join(ids)}, or numbers 1-{len(ids)})")
    if pair[0] is pair[1]:
        raise ValueError("the pair needs two different cameras")
    return tuple(pair)


def _ask(question: str, parse):
    """Ask until `parse` accepts the answer; InputError at the end of the input."""
    from camnet.errors import InputError

    while True:
        try:
            answer = input(question)
        except EOFError:
            raise InputError("no answer on the input; give --pair LEFT RIGHT and --baseline LENGTH") from None
        try:
            return parse(answer)
        except ValueError as exc:
            print(f"  {exc}", flush=True)


def _checked_output(args: argparse.Namespace) -> tuple[Path, str]:
    from camnet.errors import InputError
    from camnet.ids import validate_id

    output = Path(args.output)
    if output.exists() and not args.force:
        raise InputError(f"{output} exists; give --force to replace it, or -o another file")
    if output.is_dir():
        raise InputError(f"-o: {output} is a directory; name a file")
    if not output.absolute().parent.is_dir():
        raise InputError(f"-o: {output.parent} is no directory; make it first")
    name = args.name or output.stem
    validate_id(name, what="--name")
    if args.baseline is not None:
        try:
            parse_length_m(args.baseline)
        except ValueError as exc:
            raise InputError(f"--baseline: {exc}") from None
    return output, name


def run(args: argparse.Namespace) -> int:
    import yaml

    from camnet.commands.cameras import discover, rig_document
    from camnet.errors import InputError
    from camnet.io.atomic import write_text_atomic
    from camnet.io.rig import parse_rig

    output, name = _checked_output(args)
    if args.images is not None:
        return _run_images(args, output, name)
    found = discover(aravis_fake=args.aravis_fake)
    cameras = [c for c in found.cameras if c.problem is None]
    for cam in found.cameras:
        if cam.problem is not None:
            print(f"left out {cam.suggested_id}: {cam.problem}", flush=True)
    if len(cameras) < 2:
        raise InputError(f"found {len(cameras)} camera(s) to use ({'; '.join(found.lines)}); a rig needs two "
                         "for its stereo pair: check the cables and `camnet cameras`")
    print(f"found {len(cameras)} cameras:")
    for number, cam in enumerate(cameras, 1):
        print(f"  {number}  {cam.suggested_id:<20} {cam.description}")
    if args.pair:
        try:
            left, right = pick_pair(args.pair, cameras)
        except ValueError as exc:
            raise InputError(f"--pair: {exc}") from None
    else:
        left, right = _ask("stereo pair, left then right (numbers or ids): ", lambda a: pick_pair(a.split(), cameras))
    baseline_m = parse_length_m(args.baseline) if args.baseline is not None else _ask(
        f"baseline, the distance between the centres of {left.suggested_id} and {right.suggested_id}, "
        f"with its unit ({EXAMPLES}): ", parse_length_m)
    stereo = {"left": left.suggested_id, "right": right.suggested_id, "baseline_m": baseline_m, "parallel": False}
    doc = rig_document(name, cameras, stereo)
    rig = parse_rig(doc, source=str(output), base_dir=output.parent)  # what camnet up will read, checked now
    write_text_atomic(output, HEADER + yaml.safe_dump(doc, sort_keys=False))
    print(f"wrote {output}: rig {rig.name!r}, {len(rig.cameras)} cameras, stereo pair {left.suggested_id} and "
          f"{right.suggested_id} {baseline_m:g} m apart")
    print(f"next: camnet cameras --preview (framing, overlap); camnet up {output}")
    return 0


IMAGES_FPS = 2.0  # a sequence without timestamps is published at this rate: a few frame sets a second to match
FILL_IN = "FILL_IN"  # the placeholder of the baseline: not a number, so the stereo line fails until it is one


def _run_images(args: argparse.Namespace, output: Path, name: str) -> int:
    """`camnet init --images DIR`: the rig file of a folder of images."""
    from camnet.errors import InputError
    from camnet.io.atomic import write_text_atomic
    from camnet.io.image_folders import image_sources
    from camnet.io.rig import parse_rig

    if args.aravis_fake:
        raise InputError("--aravis-fake: looks for cameras, not with --images")
    directory = Path(args.images)
    sources = image_sources(directory)
    if len(sources) < 2:
        raise InputError(f"{directory}: the images of one camera ({sources[0].camera_id}); a rig needs two for its "
                         "stereo pair")
    pair = None
    if args.pair:
        try:
            pair = tuple(s.camera_id for s in pick_pair(args.pair, sources, id_of=attrgetter("camera_id")))
        except ValueError as exc:
            raise InputError(f"--pair: {exc}") from None
    baseline_m = parse_length_m(args.baseline) if args.baseline is not None else None
    left, right = pair or (sources[0].camera_id, sources[1].camera_id)
    stereo = {"left": left, "right": right, "baseline_m": baseline_m, "parallel": False}
    complete = pair is not None and baseline_m is not None
    doc = {"rig": name, **({"stereo": stereo} if complete else {}),
           "cameras": [_image_camera(s, output.parent) for s in sources]}
    rig = parse_rig(doc, source=str(output), base_dir=output.parent)  # what its consumer will read, checked now
    print(f"found {len(sources)} cameras in {directory}:")
    for number, source in enumerate(sources, 1):
        what = (f"{len(source.files)} image{'s' * (len(source.files) > 1)} in {source.folder}" if source.folder
                else str(source.files[0]))
        stamps = f", stamped by {source.timestamps.name}" if source.timestamps is not None else ""
        print(f"  {number}  {source.camera_id:<20} {source.width}x{source.height} "
              f"{'colour' if source.colour else 'grey'}, {what}{stamps}")
    write_text_atomic(output, _images_rig_text(directory, doc, sources, None if complete else stereo,
                                               guessed=pair is None))
    pair_text = f"stereo pair {left} and {right} {baseline_m:g} m apart" if complete else \
        f"the stereo pair and its baseline to fill in (the lines marked {FILL_IN})"
    print(f"wrote {output}: rig {rig.name!r}, {len(rig.cameras)} cameras, {pair_text}")
    sequences = sources[0].folder is not None
    run = f"camnet up {output}" if sequences else (
        f"camnet match {' '.join(str(s.files[0]) for s in sources)} --rig {output} -o observations.json, "
        "then camnet calibrate observations.json -o calibration.json")
    print(f"next: {run}" if complete else f"next: fill in the stereo pair and its baseline in {output}, then {run}")
    if sequences and not any(s.timestamps for s in sources) and any(len(s.files) > 1 for s in sources):
        print(f"note: the sequences have no {sources[0].folder.name}/timestamps.txt: their frames pair by when "
              "camnet publishes them, right for a still scene only; give each camera a timestamps.txt "
              "(config/README.md, v4l2) for a moving one")
    return 0


def _image_camera(source, rig_dir: Path) -> dict:
    """A camera of the rig file for `source`: a v4l2 image sequence, or, for one image file, an id alone."""
    import glob
    import os

    if source.folder is None:
        return {"id": source.camera_id}
    folder = Path(os.path.relpath(source.folder.absolute(), rig_dir.absolute())).as_posix()
    v4l2 = {"source": f"{glob.escape(folder)}/*{source.files[0].suffix}", "width": source.width,
            "height": source.height, "encoding": "bgr8" if source.colour else "mono8", "loop": True}
    if source.timestamps is not None:
        v4l2["timestamps"] = Path(os.path.relpath(source.timestamps.absolute(), rig_dir.absolute())).as_posix()
    else:
        v4l2["fps"] = IMAGES_FPS
    return {"id": source.camera_id, "driver": "v4l2", "v4l2": v4l2}


def _images_rig_text(directory: Path, doc: dict, sources, placeholder: dict | None, *, guessed: bool) -> str:
    """The rig file: a header, the rig, its stereo line (commented out and marked when `placeholder` gives it),
    the cameras, each with a comment on its images."""
    import yaml

    def dump(part: dict, *, flow: bool = False) -> str:  # flow: the section on one line
        return yaml.safe_dump(part, sort_keys=False, default_flow_style=None if flow else False, width=1000)

    header = (f"# Written by camnet init from the images in {directory} (paths are relative to this file). Set\n"
              "# stereo.parallel: true for a parallel head (side by side, looking the same way); known intrinsics\n"
              "# and the other keys: config/README.md.\n")
    text = header + dump({"rig": doc["rig"]})
    if placeholder is not None:
        guess = "; the line below guesses the first two" if guessed else ""
        text += (f"# {FILL_IN} before calibrating: the stereo pair (two camera ids, left then right{guess}) and\n"
                 "# the distance between their centres in metres (0.12 for 120 mm); then take the '# ' off the\n"
                 "# stereo line. Until then camnet refuses the rig: the pair's known distance gives the scale.\n"
                 + "# " + dump({"stereo": {**placeholder, "baseline_m": FILL_IN}}, flow=True))
    elif "stereo" in doc:
        text += dump({"stereo": doc["stereo"]}, flow=True)
    text += "cameras:\n"
    for camera, source in zip(doc["cameras"], sources, strict=True):
        first, *rest = dump([camera]).splitlines(keepends=True)
        images = f"{len(source.files)} images" if source.folder is not None else source.files[0].name
        kind = "colour" if source.colour else "grey"
        text += f"{first.rstrip()}  # {images}, {source.width}x{source.height} {kind}\n" + "".join(rest)
    return text
