"""`camnet init`: write a rig file of the cameras this host sees, with the stereo pair and its baseline.

It asks which two cameras form the pair and how far apart their centres
are, a length with its unit (``120 mm``, ``0.12 m``, ``12 cm``); `--pair`
and `--baseline` answer without asking. The file is checked by camnet's rig
loader before it is written, and an existing file is replaced only with
`--force`.
"""

from __future__ import annotations

import argparse
import re
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
                             "asked when not given")
    parser.add_argument("--baseline", metavar="LENGTH",
                        help=f"the distance between the pair's centres, with its unit: {EXAMPLES}; "
                             "asked when not given")
    parser.add_argument("--name", help="the rig's name (default: the file's name, e.g. rig)")
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


def pick_pair(words: list[str], cameras) -> tuple:
    """The two cameras `words` name (ids or 1-based numbers); ValueError naming what is wrong."""
    ids = [c.suggested_id for c in cameras]
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
