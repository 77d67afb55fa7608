"""Where a Rerun recording goes: the repeatable ``--rerun SINK`` flag, parsed into `RerunSink` values.

`camnet.viz.open_recording` opens the sinks; this module only parses and
checks them, so a bad flag is an `InputError` before anything starts, and
Rerun is not imported.
"""

from __future__ import annotations

import argparse
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Literal
from urllib.parse import quote

from camnet.errors import InputError

log = logging.getLogger(__name__)

DEFAULT_GRPC_PORT = 9876  # Rerun's own defaults
DEFAULT_WEB_PORT = 9090
SINK_KINDS = ("spawn", "connect", "serve", "save")
FLAG_HELP = "spawn, connect[=URL], serve[=WEB_PORT[,GRPC_PORT]] or save=FILE.rrd"


@dataclass(frozen=True)
class RerunSink:
    """Where a recording goes: one parsed ``--rerun`` value.

    kind: ``spawn`` (start a native viewer on `grpc_port` and stream to it),
    ``connect`` (stream to the viewer or server at `url`), ``serve`` (host a
    gRPC server on `grpc_port` and Rerun's web viewer on `web_port`) or
    ``save`` (write the .rrd file `path`).
    """

    kind: Literal["spawn", "connect", "serve", "save"]
    url: str = ""
    path: str = ""
    grpc_port: int = DEFAULT_GRPC_PORT
    web_port: int = DEFAULT_WEB_PORT

    def describe(self, *, host: str = "localhost") -> str:
        """One line for the operator; for ``serve``, the page to open (on `host`)."""
        if self.kind == "serve":
            return f"Rerun web viewer: {web_viewer_url(host=host, web_port=self.web_port, grpc_port=self.grpc_port)}"
        if self.kind == "save":
            return f"Rerun recording: {self.path}"
        if self.kind == "connect":
            return f"Rerun: streaming to {self.url}"
        return f"Rerun: native viewer on port {self.grpc_port}"


def web_viewer_url(*, host: str, web_port: int, grpc_port: int) -> str:
    """The web viewer page on `host` that connects to the gRPC server on the same host."""
    grpc_url = f"rerun+http://{host}:{grpc_port}/proxy"
    return f"http://{host}:{web_port}/?url={quote(grpc_url, safe='')}"


def _port(text: str, value: str) -> int:
    if not text.isdigit() or not 0 < int(text) < 65536:
        raise InputError(f"--rerun {value}: {text!r} is not a port number (1-65535)")
    return int(text)


def parse_sink(value: str) -> RerunSink:
    """The sink named by one ``--rerun`` value; a bad value is an `InputError` naming the flag."""
    kind, has_arg, arg = value.partition("=")
    if kind not in SINK_KINDS:
        raise InputError(f"--rerun {value}: unknown sink {kind!r}; expected {FLAG_HELP}")
    if kind == "spawn":
        if has_arg:
            raise InputError(f"--rerun {value}: spawn takes no value")
        return RerunSink("spawn")
    if kind == "connect":
        url = arg or f"rerun+http://127.0.0.1:{DEFAULT_GRPC_PORT}/proxy"
        if not url.startswith(("rerun://", "rerun+http://", "rerun+https://")) or not url.endswith("/proxy"):
            raise InputError(f"--rerun {value}: expected a URL like rerun+http://HOST:9876/proxy")
        return RerunSink("connect", url=url)
    if kind == "serve":
        ports = arg.split(",") if arg else []
        if len(ports) > 2:
            raise InputError(f"--rerun {value}: expected serve[=WEB_PORT[,GRPC_PORT]]")
        web_port = _port(ports[0], value) if ports else DEFAULT_WEB_PORT
        grpc_port = _port(ports[1], value) if len(ports) == 2 else DEFAULT_GRPC_PORT
        if web_port == grpc_port:
            raise InputError(f"--rerun {value}: the web viewer and the gRPC server need two different ports")
        return RerunSink("serve", web_port=web_port, grpc_port=grpc_port)
    if not arg.endswith(".rrd") or arg == ".rrd":
        raise InputError(f"--rerun {value}: expected save=FILE.rrd")
    if not Path(arg).resolve().parent.is_dir():
        raise InputError(f"--rerun {value}: directory {str(Path(arg).parent)!r} does not exist")
    return RerunSink("save", path=arg)


def add_rerun_arguments(parser: argparse.ArgumentParser) -> None:
    """The repeatable ``--rerun SINK`` flag; without it nothing is sent to Rerun."""
    parser.add_argument(
        "--rerun",
        action="append",
        default=[],
        metavar="SINK",
        help=f"stream the calibration to Rerun (repeatable): {FLAG_HELP}. "
        f"serve hosts Rerun's web viewer (default ports {DEFAULT_WEB_PORT} and {DEFAULT_GRPC_PORT}) "
        "for watching a headless rig from a browser",
    )


def sinks_from_args(args: argparse.Namespace) -> tuple[RerunSink, ...]:
    """The sinks of the ``--rerun`` flags; two sinks on one port or file are an `InputError`."""
    sinks = tuple(parse_sink(value) for value in args.rerun or ())
    ports = [s.grpc_port for s in sinks if s.kind in ("spawn", "serve")]
    ports += [s.web_port for s in sinks if s.kind == "serve"]
    paths = [Path(s.path).resolve() for s in sinks if s.kind == "save"]
    if len(set(ports)) < len(ports) or len(set(paths)) < len(paths):
        raise InputError("--rerun: two sinks use the same port or file")
    for sink in sinks:
        if sink.kind == "serve":
            # Rerun binds its servers to every interface (0.0.0.0) and offers no other address.
            log.warning("RERUN SERVES ON 0.0.0.0:%d AND 0.0.0.0:%d, unencrypted and without a login: anyone "
                        "who reaches these ports sees the rig's images and calibration. Firewall them, or "
                        "reach them through an ssh tunnel (docs/security.md)", sink.web_port, sink.grpc_port)
    return sinks


__all__ = ["FLAG_HELP", "RerunSink", "add_rerun_arguments", "parse_sink", "sinks_from_args", "web_viewer_url"]
