"""A secured rig on loopback: `camnet secure init` secrets, `camnet router --secure` as a process,
nodes as Zenoh clients with their own identities, and Zenoh's access control deciding who may
say what. Forged observations, frames and calibrations from the wrong identity, and peers with
no or a foreign certificate, never reach the calibrator; the calibration it published stands."""

from __future__ import annotations

import json
import logging
import shutil
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path

import pytest

from camnet.bus import keys
from camnet.bus.security import IDENTITIES, ROUTER, access_control, common_name, load_secure_dir, zenoh_settings
from camnet.bus.session import BusOptions, make_config, open_session
from camnet.errors import InputError
from tests.conftest import free_port, logs_written, matched_publisher, running_node, wait_for

RIG = "securig"
ROOT = Path(__file__).resolve().parents[1]
needs_openssl = pytest.mark.skipif(shutil.which("openssl") is None, reason="camnet secure init needs the openssl CLI")


def camnet(*argv: str, timeout_s: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "camnet.cli", *argv], cwd=ROOT, capture_output=True, text=True,
                          timeout=timeout_s)


@pytest.fixture(scope="module")
def secrets(tmp_path_factory) -> Path:
    if shutil.which("openssl") is None:
        pytest.skip("camnet secure init needs the openssl CLI")
    directory = tmp_path_factory.mktemp("rig") / "secrets"
    done = camnet("secure", "init", str(directory), "--rig", RIG)
    assert done.returncode == 0, done.stderr
    return directory


@pytest.fixture(scope="module")
def foreign_secrets(tmp_path_factory) -> Path:
    """Another rig's secrets: a CA the router does not trust, with the same identity names."""
    if shutil.which("openssl") is None:
        pytest.skip("camnet secure init needs the openssl CLI")
    directory = tmp_path_factory.mktemp("other") / "secrets"
    assert camnet("secure", "init", str(directory), "--rig", RIG).returncode == 0
    return directory


@contextmanager
def router_process(secrets: Path, log_path: Path, port: int | None = None):
    """`camnet router --secure` on `port` of loopback (default: a free one): (endpoint nodes dial, its log).
    Run as docker/compose.yaml runs it, without -v: its log is what a deployment's shows."""
    port = port or free_port()
    with open(log_path, "wb") as log:
        process = subprocess.Popen(
            [sys.executable, "-m", "camnet.cli", "router", "--secure", str(secrets),
             "--listen", f"tls/127.0.0.1:{port}"], cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)
    try:
        # Progress, not a fixed delay: the router prints once it listens (a loaded machine is slow to start).
        assert wait_for(lambda: "listening on" in log_path.read_text() or process.poll() is not None, 120), \
            "router did not start"
        assert process.poll() is None, log_path.read_text()
        yield f"tls/localhost:{port}", log_path
    finally:
        stop(process)


def stop(process: subprocess.Popen) -> None:
    """End a process this test started: politely, then for sure."""
    process.terminate()
    try:
        process.wait(timeout=30)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()


def client(secrets: Path, identity: str, endpoint: str):
    return open_session(BusOptions(secure=str(secrets), identity=identity, connect=(endpoint,)))


def intruder(secrets: Path, identity: str, endpoint: str, changes: dict):
    """A client session of `identity` with Zenoh `changes` to its config, or the ZError that kept it
    out (tried once, for 5 s unless `changes` say otherwise, instead of waiting for the router as nodes do)."""
    import zenoh

    config = make_config(BusOptions(secure=str(secrets), identity=identity, connect=(endpoint,)))
    for key, value in {"connect/timeout_ms": 5000, **changes}.items():
        config.insert_json5(key, json.dumps(value))
    try:
        return zenoh.open(config)
    except zenoh.ZError as exc:
        return exc


# --- secrets and configuration ------------------------------------------------------------


def test_init_writes_private_secrets_with_one_identity_per_node_kind(secrets):
    assert secrets.stat().st_mode & 0o777 == 0o700
    for identity in IDENTITIES:
        assert (secrets / f"{identity}-key.pem").stat().st_mode & 0o777 == 0o600, identity
        subject = subprocess.run(["openssl", "x509", "-in", str(secrets / f"{identity}.pem"), "-noout", "-subject"],
                                 capture_output=True, text=True, check=True).stdout
        assert common_name(identity) in subject, subject
        verify = subprocess.run(["openssl", "verify", "-CAfile", str(secrets / "ca.pem"),
                                 str(secrets / f"{identity}.pem")], capture_output=True, text=True)
        assert verify.returncode == 0, verify.stdout + verify.stderr
    assert (secrets / "ca-key.pem").stat().st_mode & 0o777 == 0o600
    sans = subprocess.run(["openssl", "x509", "-in", str(secrets / "router.pem"), "-noout", "-ext", "subjectAltName"],
                          capture_output=True, text=True, check=True).stdout
    assert "DNS:localhost" in sans and "IP Address:127.0.0.1" in sans
    secure = load_secure_dir(secrets, "driver")
    assert secure.rig == RIG and secure.router_endpoints == ("tls/localhost:7447",)


@needs_openssl
def test_init_refuses_to_overwrite_and_names_the_router_hosts(tmp_path):
    target = tmp_path / "s"
    done = camnet("secure", "init", str(target), "--rig", "lab", "--router-host", "rig-router.lan",
                  "--router-host", "10.0.0.5", "--port", "7500")
    assert done.returncode == 0, done.stderr
    assert load_secure_dir(target, "matcher").router_endpoints == ("tls/rig-router.lan:7500", "tls/10.0.0.5:7500")
    sans = subprocess.run(["openssl", "x509", "-in", str(target / "router.pem"), "-noout", "-ext", "subjectAltName"],
                          capture_output=True, text=True, check=True).stdout
    assert "DNS:rig-router.lan" in sans and "IP Address:10.0.0.5" in sans
    key = (target / "driver-key.pem").read_text()
    again = camnet("secure", "init", str(target), "--rig", "lab")
    assert again.returncode == 2 and "--force" in again.stderr and again.stderr.count("\n") == 1
    assert (target / "driver-key.pem").read_text() == key
    bad = camnet("secure", "init", str(tmp_path / "t"), "--rig", "a*b")
    assert bad.returncode == 2 and "--rig" in bad.stderr and bad.stderr.count("\n") == 1
    assert not (tmp_path / "t").exists()
    assert camnet("secure", "init", str(target), "--rig", "lab", "--force").returncode == 0
    assert (target / "driver-key.pem").read_text() != key
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s"], "scratch or old directories left behind"


def test_bad_secure_directories_are_one_line_errors(tmp_path, secrets):
    with pytest.raises(InputError, match="camnet secure init"):
        make_config(BusOptions(secure=str(tmp_path), identity="driver"))
    partial = tmp_path / "partial"
    partial.mkdir()
    for name in ("secure.json", "ca.pem"):
        shutil.copy(secrets / name, partial / name)
    with pytest.raises(InputError, match="driver.pem missing"):
        make_config(BusOptions(secure=str(partial), identity="driver"))
    with pytest.raises(InputError, match="listens on nothing"):
        make_config(BusOptions(secure=str(secrets), identity="driver", listen=("tls/127.0.0.1:7000",)))
    with pytest.raises(InputError, match="not TLS"):
        make_config(BusOptions(secure=str(secrets), identity="driver", connect=("tcp/127.0.0.1:7447",)))


def test_each_key_is_granted_to_the_kinds_whose_job_it_is():
    acl = access_control(RIG)
    assert acl["enabled"] and acl["default_permission"] == "deny"
    rules = {rule["id"]: rule for rule in acl["rules"]}
    subjects = {s["id"]: s for s in acl["subjects"]}
    allowed: dict[tuple[str, str], set[str]] = {}
    for policy in acl["policies"]:
        [subject] = policy["subjects"]
        [name] = subjects[subject]["cert_common_names"]
        for rule_id in policy["rules"]:
            rule = rules[rule_id]
            for message in rule["messages"]:
                for flow in rule["flows"]:
                    for key in rule["key_exprs"]:
                        allowed.setdefault((f"{message} {flow}", key), set()).add(name)

    def who(action: str, key: str) -> set[str]:
        return {name.removeprefix("camnet-") for (a, k), names in allowed.items() if a == action
                for name in names if keys_include(k, key)}

    assert who("put ingress", keys.frame(RIG, "left")) == {"driver", "replayer"}
    assert who("put ingress", keys.features(RIG, "left")) == {"driver", "replayer"}
    assert who("put egress", keys.features(RIG, "left")) == {"matcher", "recorder"}
    assert who("put ingress", keys.observations(RIG)) == {"matcher"}
    assert who("put ingress", keys.calibration(RIG)) == {"calibrator"}
    assert who("declare_queryable ingress", keys.calibration(RIG)) == {"calibrator"}
    assert who("put egress", keys.observations(RIG)) == {"calibrator", "recorder", "observer"}
    # The matcher reads the calibration to choose its pairs, and the features of the cameras' stages.
    assert who("put ingress", keys.features(RIG, "left")) == {"driver", "replayer"}
    assert who("put egress", keys.features(RIG, "left")) == {"matcher", "recorder"}
    assert who("liveliness_token ingress", keys.node(RIG, "features", "left")) == {"driver"}
    assert who("put egress", keys.calibration(RIG)) == {"matcher", "recorder", "observer"}
    # Who reads calibrations takes them only from a session a calibrator's token names.
    calibrator = keys.calibrator(RIG, "4ba47ec6cc3c913134b083514c2c9f94")
    assert who("liveliness_token ingress", calibrator) == {"calibrator"}
    assert who("liveliness_token egress", calibrator) == {"matcher", "recorder"}
    # A restarted matcher asks for the latest calibration; the cameras' stages follow its pace.
    assert who("query ingress", keys.calibration(RIG)) == {"matcher", "recorder", "observer"}
    assert who("put egress", keys.node_stats(RIG, "matcher", "matcher")) == {"driver", "recorder", "observer"}
    assert who("liveliness_token ingress", keys.node(RIG, "matcher", "matcher")) == {"matcher"}
    assert who("liveliness_token ingress", keys.node(RIG, "driver", "left")) == {"driver", "replayer"}
    assert who("put ingress", keys.node_stats(RIG, "calibrator", "calibrator")) == {"calibrator"}
    assert not who("put ingress", keys.frame("otherrig", "left")), "another rig's keys are granted"
    # Only the recorder subscribes to everything; every publisher learns of it (a client sends
    # only what a subscriber it knows of wants), and of status's statistics subscriber.
    everything = f"{keys.rig_prefix(RIG)}/**"
    assert who("declare_subscriber ingress", everything) == {"recorder"}
    publishers = {"driver", "replayer", "matcher", "calibrator", "recorder"}
    assert who("declare_subscriber egress", everything) == who("declare_subscriber egress",
                                                               keys.all_node_stats(RIG)) == publishers


def keys_include(pattern: str, key: str) -> bool:
    import zenoh

    return zenoh.KeyExpr(pattern).includes(zenoh.KeyExpr(key))


def test_router_settings_demand_certificates_and_listen_on_tls_only(secrets):
    secure = load_secure_dir(secrets, ROUTER)
    settings = zenoh_settings(secure, ROUTER)
    assert settings["mode"] == "router" and settings["transport/link/protocols"] == ["tls"]
    assert settings["transport/link/tls/enable_mtls"] is True
    assert settings["listen/endpoints"] == ["tls/[::]:7447"]
    node = zenoh_settings(load_secure_dir(secrets, "driver"), "driver")
    assert node["mode"] == "client" and node["connect/endpoints"] == ["tls/localhost:7447"]


def test_the_router_listens_on_the_port_secure_init_gave(tmp_path):
    """`secure init --port P` tells the nodes to dial P: the router started with no --listen is there."""
    if shutil.which("openssl") is None:
        pytest.skip("camnet secure init needs the openssl CLI")
    port, directory = free_port(), tmp_path / "secrets"
    done = camnet("secure", "init", str(directory), "--rig", RIG, "--port", str(port))
    assert done.returncode == 0, done.stderr
    log_path = tmp_path / "router.log"
    with open(log_path, "wb") as log:
        process = subprocess.Popen([sys.executable, "-m", "camnet.cli", "router", "--secure", str(directory)],
                                   cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)
    try:
        assert wait_for(lambda: "listening on" in log_path.read_text() or process.poll() is not None, 120), \
            "router did not start"
        assert f"listening on tls/[::]:{port};" in log_path.read_text(), log_path.read_text()
        # A node that dials where the secure directory says gets in.
        session = intruder(directory, "driver", f"tls/localhost:{port}", {})
        assert not isinstance(session, Exception), f"{session}\n{log_path.read_text()}"
        session.close()
    finally:
        stop(process)


# --- access control on loopback -----------------------------------------------------------


def stranger_secrets(secrets: Path, tmp_path: Path) -> Path:
    """A copy of the rig's secrets for a certificate the rig's CA signed, naming no identity."""
    stranger = tmp_path / "stranger"
    shutil.copytree(secrets, stranger)
    openssl = ["openssl", "req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes",
               "-subj", "/CN=camnet-intruder", "-keyout", "driver-key.pem", "-out", "intruder.csr"]
    subprocess.run(openssl, cwd=stranger, capture_output=True, check=True)
    (stranger / "intruder.ext").write_text("basicConstraints=critical,CA:FALSE\nextendedKeyUsage=clientAuth\n")
    subprocess.run(["openssl", "x509", "-req", "-in", "intruder.csr", "-CA", "ca.pem", "-CAkey", "ca-key.pem",
                    "-CAcreateserial", "-days", "1", "-extfile", "intruder.ext", "-out", "driver.pem"], cwd=stranger,
                   capture_output=True, check=True)
    return stranger


def calibrator_running(session, state_path: Path):
    from camnet.services.calibrator import CalibratorConfig, CalibratorNode

    return running_node(CalibratorNode(session, RIG, CalibratorConfig(state_path=state_path)))


def test_only_authorised_identities_reach_the_calibrator(secrets, foreign_secrets, tmp_path):
    import zenoh

    from tests.test_calibrator_node import observations_payload

    block = zenoh.CongestionControl.BLOCK  # every forgery is sent: none may be lost on the way out
    with router_process(secrets, tmp_path / "router.log") as (endpoint, router_log):
        sessions = {identity: client(secrets, identity, endpoint)
                    for identity in ("calibrator", "matcher", "driver", "observer")}
        no_tls_client_certificate = {"transport/link/tls/enable_mtls": False,
                                     "transport/link/tls/connect_certificate": None,
                                     "transport/link/tls/connect_private_key": None}
        attempts = {
            "no certificate": (secrets, "driver", no_tls_client_certificate),
            # Trusts the rig's router, but its own certificate comes from another rig's CA.
            "another CA": (foreign_secrets, "matcher",
                           {"transport/link/tls/root_ca_certificate": str(secrets / "ca.pem")}),
            # Let in by TLS (its CA is the rig's): given as long as a loaded machine takes to connect.
            "stranger": (stranger_secrets(secrets, tmp_path), "driver", {"connect/timeout_ms": 60_000}),
        }
        with ThreadPoolExecutor(len(attempts)) as pool:  # the refused ones each wait out their timeout
            futures = {name: pool.submit(intruder, d, identity, endpoint, changes)
                       for name, (d, identity, changes) in attempts.items()}
        refused = {name: future.result() for name, future in futures.items()}
        stranger = refused.pop("stranger")
        calibrator, matcher, driver, observer = (sessions[k] for k in ("calibrator", "matcher", "driver", "observer"))
        try:
            for name, session in refused.items():
                assert isinstance(session, zenoh.ZError), f"{name}: the router let it in"
            assert not isinstance(stranger, Exception), f"a CA-signed stranger cannot even connect: {stranger}"
            seen = {"observations": [], "frames": [], "calibrations": [], "stats": []}

            def keep(kind):
                return lambda sample: seen[kind].append(bytes(sample.payload.to_bytes()))

            # What the calibrator's identity receives, beside the calibrator node on the same session.
            calibrator.declare_subscriber(keys.observations(RIG), keep("observations"))
            calibrator.declare_subscriber(keys.all_frames(RIG), keep("frames"))
            observer.declare_subscriber(keys.calibration(RIG), keep("calibrations"))
            observer.declare_subscriber(keys.all_node_stats(RIG), keep("stats"))
            with calibrator_running(calibrator, tmp_path / "state.json") as node:
                # Its first statistics follow its subscriptions: the observations cannot arrive before it listens.
                assert wait_for(lambda: seen["stats"], 60), "the calibrator published no statistics"
                # The matcher's observations are solved, and the calibration is published.
                good = observations_payload(seed=1)
                matched_publisher(matcher, keys.observations(RIG), 60).put(good)
                assert wait_for(lambda: seen["calibrations"], 180), "no calibration from the matcher's observations"
                [published] = seen["calibrations"]
                frames = matched_publisher(driver, keys.frame(RIG, "left"), 60)
                frames.put(b"frame 0")
                assert wait_for(lambda: seen["frames"] == [b"frame 0"], 60), seen["frames"]

                forged = observations_payload(seed=7)
                forged_calibration = json.dumps({**json.loads(published), "solve": 99}).encode()
                for _ in range(20):  # 20 of each over 5 s, as an attack on an open rig sends them
                    driver.put(keys.observations(RIG), forged, congestion_control=block)
                    driver.put(keys.calibration(RIG), forged_calibration, congestion_control=block)
                    observer.put(keys.observations(RIG), forged, congestion_control=block)
                    matcher.put(keys.frame(RIG, "left"), b"forged by the matcher", congestion_control=block)
                    stranger.put(keys.observations(RIG), forged, congestion_control=block)
                    stranger.put(keys.frame(RIG, "right"), b"forged by a stranger", congestion_control=block)
                    time.sleep(0.25)
                # Each link is in order: what an intruder may send, sent after its forgeries, arriving
                # means the router has dealt with them. The stranger may send nothing: its query
                # goes unanswered, and its timeout is the wait.
                frames.put(b"frame 1")
                matcher.put(keys.node_stats(RIG, "matcher", "matcher"), b"{}", congestion_control=block)
                answers = [r.ok for r in observer.get(keys.calibration(RIG), timeout=30.0) if r.ok is not None]
                assert [r.ok for r in stranger.get(keys.calibration(RIG), timeout=3.0) if r.ok] == []
                assert wait_for(lambda: b"frame 1" in seen["frames"] and b"{}" in seen["stats"], 60)
                assert [bytes(a.payload.to_bytes()) for a in answers] == [published], \
                    "the published calibration changed"
                assert seen["observations"] == [good], f"{len(seen['observations']) - 1} forged observations arrived"
                assert seen["frames"] == [b"frame 0", b"frame 1"], f"forged frames arrived: {seen['frames']}"
                assert seen["calibrations"] == [published], "a forged calibration arrived"
                assert node.tracker.solves == 1 and node.mailbox.superseded == 0
                # The rig's calibration is its owner's alone.
                assert (tmp_path / "state.json").stat().st_mode & 0o777 == 0o600
        finally:
            for session in (*sessions.values(), stranger):
                if not isinstance(session, Exception):
                    session.close()
        log = router_log.read_text()
    # Every refusal is in the router's log: Zenoh's own lines for the TLS handshakes it failed,
    # camnet's and Zenoh's for the certificate that names no identity.
    assert "sent no certificates" in log, log
    assert "invalid peer certificate" in log, log
    assert "'camnet-intruder', which names no camnet identity" in log, log
    assert "did not match any configured ACL subject" in log, log
    assert "admitted the calibrator (camnet-calibrator)" in log, log


# --- outages and the whole network ---------------------------------------------------------


def test_a_node_logs_losing_its_router_and_getting_it_back(secrets, tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="camnet.bus.session")
    port = free_port()
    with router_process(secrets, tmp_path / "router1.log", port) as (endpoint, _):
        node = client(secrets, "matcher", endpoint)
    try:
        assert wait_for(lambda: "lost the router" in caplog.text, 60), caplog.text
        assert "reached again" not in caplog.text
        with router_process(secrets, tmp_path / "router2.log", port):
            # Zenoh retries every few seconds; the new router is up when its process says so.
            assert wait_for(lambda: "reached again after" in caplog.text, 60), caplog.text
            assert wait_for(lambda: list(node.info.routers_zid()), 30)
    finally:
        node.close()
    lines = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any(line.startswith("lost the router") for line in lines) and \
        any(line.startswith("router") and "reached again" in line for line in lines), lines


def test_a_secured_network_calibrates_records_and_lists_its_nodes(secrets, tmp_path):
    """`camnet up --secure`: every node (drivers, matcher, calibrator, recorder) does its job through
    the router's access control with its own identity, and `camnet status` (an observer) sees them."""
    from mcap.reader import make_reader

    from tests.test_network import rig_file

    rig_path = rig_file(tmp_path, 4)
    rig = "net4"
    directory = tmp_path / "secrets"
    assert camnet("secure", "init", str(directory), "--rig", rig_path).returncode == 0
    out, session = tmp_path / "calibration.json", tmp_path / "session.mcap"
    with router_process(directory, tmp_path / "router.log") as (endpoint, router_log):
        up = subprocess.Popen([sys.executable, "-m", "camnet.cli", "up", rig_path, "--duration-s", "60", "--run-dir",
                               str(tmp_path / "run"), "-o", str(out), "--record", str(session),
                               "--secure", str(directory), "--connect", endpoint],
                              cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            # The calibrator's state file appears with the first good calibration.
            # As long as its nodes log their work (a loaded machine is slow to start six of them, and to finish).
            running = {"progress": lambda: logs_written(tmp_path / "run"), "limit_s": 900}
            assert wait_for(lambda: (tmp_path / "run" / "calibration.json").exists() or up.poll() is not None, 150,
                            **running)
            status = camnet("status", "--rig", rig, "--secure", str(directory), "--connect", endpoint)
            assert wait_for(lambda: up.poll() is not None, 150, 0.5, **running), "camnet up did not end"
            output, _ = up.communicate(timeout=60)
        finally:
            if up.poll() is None:
                up.terminate()
                up.wait(timeout=60)
    logs = "\n".join(p.read_text()[-1500:] for p in (tmp_path / "run").glob("*.log"))
    assert up.returncode == 0, output + logs + router_log.read_text()
    assert "final calibration" in output and out.exists()
    assert status.returncode == 0, status.stderr
    rows = {tuple(line.split()[:2]): line for line in status.stdout.splitlines()}
    for kind, node_id in [("driver", "left"), ("driver", "mono_b"), ("matcher", "matcher"),
                          ("calibrator", "calibrator"), ("recorder", "recorder")]:
        # Listed from its liveliness token, with the statistics it published.
        assert "no statistics" not in rows.get((kind, node_id), "no statistics"), status.stdout
    with open(session, "rb") as f:
        topics = {channel.topic for channel in make_reader(f).get_summary().channels.values()}
    assert {keys.frame(rig, "left"), keys.observations(rig), keys.calibration(rig)} <= topics
    assert "names no camnet identity" not in router_log.read_text()


def test_a_lockstep_replay_runs_through_the_access_control(tmp_path):
    """The replayer's identity (frames as a driver, lockstep steps, the acknowledgements and their
    liveliness) and the lockstep side of the matcher and calibrator are granted what they use."""
    from camnet.bus.launch import Launch
    from tests.test_network import rig_file
    from tests.test_replay_lockstep import write_session

    rig_path = rig_file(tmp_path, 4)
    session = tmp_path / "session.mcap"
    write_session(session, rig_path)
    directory = tmp_path / "secrets"
    assert camnet("secure", "init", str(directory), "--rig", rig_path).returncode == 0
    with router_process(directory, tmp_path / "router.log") as (endpoint, router_log), \
            Launch(tmp_path / "run") as launch:
        (tmp_path / "run").mkdir()
        flags = ["--secure", str(directory), "--connect", endpoint]
        launch.start("matcher", ["matcher", "--rig", rig_path, "--lockstep", *flags])
        launch.start("calibrator", ["calibrator", "--rig", rig_path, "--no-state", "--lockstep", *flags])
        replay = camnet("replay", str(session), "--lockstep", "--wait-s", "120", "--ack-timeout-s", "120", *flags,
                        timeout_s=400)
        logs = "\n".join(f"--- {c.name}\n{c.log_tail()}" for c in launch.children)
    assert replay.returncode == 0, replay.stdout + replay.stderr + logs + router_log.read_text()
    [line] = [line for line in replay.stdout.splitlines() if line.startswith("lockstep: ")]
    counts = dict(part.split() for part in line.removeprefix("lockstep: ").split(", "))
    assert int(counts.get("good", 0)) >= 1, line


def test_a_node_started_before_its_router_waits_for_it_saying_so(secrets, tmp_path, caplog):
    import threading

    caplog.set_level(logging.WARNING, logger="camnet.bus.session")
    port = free_port()
    opened = []
    # A daemon thread: a node that never connects fails the test below instead of hanging it.
    waiting = threading.Thread(daemon=True, target=lambda: opened.append(
        client(secrets, "driver", f"tls/localhost:{port}")))
    waiting.start()
    try:
        # Each try gives up after security.CONNECT_TRY_MS (10 s), says so, and tries again.
        assert wait_for(lambda: "no router answers at tls/localhost" in caplog.text, 120), caplog.text
        assert not opened
        with router_process(secrets, tmp_path / "router.log", port):
            waiting.join(timeout=120)
            assert opened, "the node did not join the router that came up"
            assert wait_for(lambda: list(opened[0].info.routers_zid()), 30)
    finally:
        for session in opened:
            session.close()


def test_a_camera_host_sends_its_features_through_the_access_control(secrets, tmp_path):
    """`camnet driver --camera A --camera B --features --secure`: one process with the drivers' identity
    publishes both cameras' frames and features, and the router passes them to the matcher."""
    from camnet.bus.features_wire import decode_features
    from tests.test_driver_command import small_rig

    rig_path = small_rig(tmp_path / "rig.yaml", name=RIG)
    with router_process(secrets, tmp_path / "router.log") as (endpoint, router_log):
        with open(tmp_path / "driver.log", "wb") as log:
            driver = subprocess.Popen([sys.executable, "-m", "camnet.cli", "driver", "sim", "--rig", str(rig_path),
                                       "--camera", "left", "--camera", "mono_a", "--features", "--features-period-s",
                                       "0.5", "--secure", str(secrets), "--connect", endpoint],
                                      cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)
        try:
            seen: dict[str, set[str]] = {"frames": set(), "features": set()}

            def on_features(sample) -> None:
                seen["features"].add(decode_features(sample.payload.to_bytes()).camera_id)

            with client(secrets, "matcher", endpoint) as matcher:
                matcher.declare_subscriber(keys.all_frames(RIG), lambda s: seen["frames"].add(str(s.key_expr)))
                matcher.declare_subscriber(keys.all_features(RIG), on_features)
                # Progress, not a fixed delay: both cameras' features and frames arrive (or the driver ends).
                # A camera's features can come before any of its frames does (on a loaded machine).
                frames = {keys.frame(RIG, "left"), keys.frame(RIG, "mono_a")}
                assert wait_for(lambda: (seen["features"] == {"left", "mono_a"} and seen["frames"] == frames)
                                or driver.poll() is not None, 120), \
                    (seen, (tmp_path / "driver.log").read_text()[-2000:], router_log.read_text()[-2000:])
                assert seen["features"] == {"left", "mono_a"} and seen["frames"] == frames
        finally:
            stop(driver)
    assert driver.returncode == 0, (tmp_path / "driver.log").read_text()[-2000:]
