"""Bus flags -> zenoh.Config, and the lazy driver registry (no sessions opened)."""

import argparse
import json
import logging
import subprocess
import sys

import numpy as np
import pytest

from camnet.bus.session import BusOptions, add_bus_arguments, listen_endpoints, make_config, options_from_args
from camnet.errors import InputError


def config_json(options: BusOptions, key: str):
    return json.loads(make_config(options).get_json(key))


def test_default_is_loopback_rendezvous_without_multicast():
    options = BusOptions()
    assert config_json(options, "mode") == "peer"
    assert config_json(options, "scouting/multicast/enabled") is False
    assert config_json(options, "listen/endpoints") == ["tcp/127.0.0.1:7447", "tcp/127.0.0.1:0"]
    assert config_json(options, "connect/endpoints") == ["tcp/127.0.0.1:7447"]
    assert config_json(BusOptions(mode="router"), "listen/endpoints") == ["tcp/127.0.0.1:7447"]


def test_flags_replace_the_defaults():
    parser = argparse.ArgumentParser()
    add_bus_arguments(parser)
    args = parser.parse_args(["--connect", "tcp/10.0.0.5:7447", "--connect", "tcp/10.0.0.6:7447",
                              "--scouting"])
    options = options_from_args(args)
    assert config_json(options, "connect/endpoints") == ["tcp/10.0.0.5:7447",
                                                         "tcp/10.0.0.6:7447"]
    assert config_json(options, "scouting/multicast/enabled") is True
    assert "tcp/127.0.0.1:7447" not in json.dumps(config_json(options, "listen/endpoints"))


def test_connect_alone_listens_on_loopback_only():
    """Zenoh's own default would listen on every interface, plain tcp."""
    assert config_json(BusOptions(connect=("tcp/10.0.0.5:7447",)), "listen/endpoints") == ["tcp/127.0.0.1:0"]
    assert config_json(BusOptions(connect=("tcp/10.0.0.5:7447",), mode="router"),
                       "listen/endpoints") == ["tcp/127.0.0.1:7447"]

def test_a_client_from_a_config_file_listens_on_nothing(tmp_path):
    client = tmp_path / "client.json5"
    client.write_text('{ mode: "client", connect: { endpoints: ["tcp/10.0.0.5:7447"] } }')
    assert listen_endpoints(make_config(BusOptions(zenoh_config=str(client)))) == []


@pytest.mark.parametrize(("endpoint", "warns"), [
    ("tcp/0.0.0.0:7447", True), ("tcp/[::]:7447", True), ("tcp/10.0.0.5:7447", True), ("udp/0.0.0.0:7447", True),
    ("tcp/rig-host.lan:7447", True), ("tcp/127.0.0.1:7447", False), ("tcp/[::1]:7447", False),
    ("tcp/localhost:7447", False), ("tls/0.0.0.0:7447", False), ("quic/[::]:7447", False),
    ("unixsock-stream//tmp/camnet.sock", False),
])
def test_listening_beyond_loopback_without_tls_warns_loudly(endpoint, warns, caplog):
    make_config(BusOptions(listen=(endpoint,)))
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert bool(warnings) == warns, warnings
    if warns:
        [line] = warnings
        assert endpoint in line and "WITHOUT TLS" in line and "--secure" in line


def test_rerun_served_on_every_interface_warns_loudly(caplog):
    from camnet.viz_sinks import sinks_from_args

    sinks_from_args(argparse.Namespace(rerun=["save=run.rrd", "connect"]))
    assert not caplog.records
    sinks_from_args(argparse.Namespace(rerun=["serve=8080,8081"]))
    [record] = caplog.records
    assert record.levelno == logging.WARNING and "0.0.0.0:8080" in record.getMessage()


def test_zenoh_config_file_and_its_errors(tmp_path):
    good = tmp_path / "z.json5"
    good.write_text('{ mode: "client", connect: { endpoints: ["tcp/127.0.0.1:7000"] } }')
    options = BusOptions(zenoh_config=str(good), listen=("tcp/127.0.0.1:7001",))
    assert config_json(options, "connect/endpoints") == ["tcp/127.0.0.1:7000"]
    assert config_json(options, "listen/endpoints") == ["tcp/127.0.0.1:7001"]
    bad = tmp_path / "bad.json5"
    bad.write_text("{ mode: ")
    with pytest.raises(InputError, match="bad.json5"):
        make_config(BusOptions(zenoh_config=str(bad)))


def test_package_imports_no_camera_sdk():
    code = ("import sys, camnet.cli, camnet.drivers.base, camnet.drivers.sim, camnet.drivers.v4l2, "
            "camnet.drivers.node; "
            "camnet.cli.build_parser(); "
            "assert 'gi' not in sys.modules, 'Aravis imported eagerly'")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


@pytest.mark.parametrize("encoding", ["mono8", "mono16", "bgr8", "rgb8"])
def test_sim_camera_encodings_and_protocol(encoding):
    from tests.test_driver_read_into import fast_sim_camera

    camera = fast_sim_camera(encoding)  # 5000 fps: slots are skipped, counted and seen as gaps
    with camera:
        frames = [camera.read(timeout_s=1.0)]
        before = camera.dropped  # slots that fell due while a loaded machine was still opening it
        frames += [camera.read(timeout_s=1.0) for _ in range(2)]
    assert frames[1].encoding == encoding and frames[1].camera_id == "right"
    seq_step = frames[2].seq - frames[1].seq
    assert frames[2].timestamp_ns - frames[1].timestamp_ns == seq_step * 200_000
    # Slots run on the common clock: every slot skipped between two frames is counted dropped.
    assert seq_step > 1 and camera.dropped - before == frames[2].seq - frames[0].seq - 2
    image = frames[1].image
    assert image.shape[:2] == (1024, 1280)
    assert image.dtype == (np.uint16 if encoding == "mono16" else np.uint8)
