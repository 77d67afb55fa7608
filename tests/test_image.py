"""docker/Dockerfile really built and run, with Podman: the image on a base made from
Debian's packages (docker/make-base.sh; no registry is needed), `camnet --version` in it,
and the secured rig in containers on a Podman network: with fresh secrets from `camnet secure
init`, a router container (`camnet router --secure`) and `camnet up --secure`'s nodes in
another, each with its own certificate and mounted as docker/compose.yaml mounts them,
produce a calibration.

Skips only where there is nothing to build on: no Podman, or no base image (make one with
docker/make-base.sh, as CI does). With both present every failure, Podman's own included,
fails the test."""

from __future__ import annotations

import json
import os
import queue
import resource
import shutil
import ssl
import subprocess
import sys
import threading
import time
import uuid
from importlib.metadata import version
from pathlib import Path

import pytest

from camnet.bus.security import COMMAND_IDENTITY
from camnet.io.formats import parse_calibration
from camnet.io.rig import load_rig
from camnet.model.accuracy import compare_cameras
from tests.test_docker import DOCKER, ROOT, camnet_services, load_compose, service_argv
from tests.test_network import rig_file

PODMAN = shutil.which("podman")
# docker/make-base.sh's base first; the Dockerfile's default where it has been pulled.
BASES = ("localhost/camnet-base:bookworm", "docker.io/library/python:3.11-slim-bookworm")
IMAGE = "localhost/camnet:test"
ROUTER_HOST = "camnet-router"  # the name the nodes dial (secure.json), as in the router's certificate
CONTAINER_UID = 1000  # the image's user, who reads the mounted secrets (docker/README.md, section 1)
# The identities `camnet up` runs with: its own (it watches the calibrations) and its nodes'.
UP_IDENTITIES = {COMMAND_IDENTITY["up"], "driver", "matcher", "calibrator"}
BUILD_TIMEOUT_S = 1800  # about 5 minutes from nothing on a 2-core machine, 1 with the layers cached
SOLVES = 2  # calibrations to wait for before stopping the rig


def podman_flags() -> list[str]:
    """Podman's global flags for this host. crun (Debian's default runtime) refuses to run
    containers where cgroups are in hybrid mode (v1 controllers with a v2 hierarchy at
    /sys/fs/cgroup/unified); runc runs them."""
    if Path("/sys/fs/cgroup/unified").is_dir() and shutil.which("runc"):
        return ["--runtime", "runc"]
    return []


def run_flags() -> list[str]:
    """`podman run` flags for every container. Podman 4 asks for 1048576 open files and
    processes unless told otherwise, which a root without CAP_SYS_RESOURCE (a sandboxed
    machine) cannot set: ask for this process's own hard limits, the process limit no higher
    than the kernel's pid_max (Podman lowers its own to that)."""
    def hard(limit: int) -> int:
        value = resource.getrlimit(limit)[1]
        return 1048576 if value == resource.RLIM_INFINITY else min(value, 1048576)

    pid_max = int(Path("/proc/sys/kernel/pid_max").read_text())
    nofile, nproc = hard(resource.RLIMIT_NOFILE), min(hard(resource.RLIMIT_NPROC), pid_max)
    return ["--ulimit", f"nofile={nofile}:{nofile}", "--ulimit", f"nproc={nproc}:{nproc}"]


def podman(*args: str, timeout: float = 120, check: bool = True) -> subprocess.CompletedProcess:
    done = subprocess.run([PODMAN, *podman_flags(), *args], capture_output=True, text=True, timeout=timeout)
    if check and done.returncode != 0:
        pytest.fail(f"podman {' '.join(args[:2])} failed ({done.returncode}):\n"
                    f"{done.stdout[-3000:]}\n{done.stderr[-3000:]}")
    return done


def host_ca_bundle() -> Path | None:
    """The CA bundle this host trusts (pip's own setting first), for pip inside the build:
    PyPI may be reached through a TLS-inspecting proxy whose CA only the host knows."""
    paths = ssl.get_default_verify_paths()
    for candidate in (os.environ.get("PIP_CERT"), paths.cafile, paths.openssl_cafile):
        if candidate and Path(candidate).is_file():
            return Path(candidate)
    return None


@pytest.fixture(scope="module")
def base_image() -> str:
    if PODMAN is None:
        pytest.skip("podman not installed (Debian: apt-get install podman runc)")
    for base in BASES:
        if podman("image", "exists", base, check=False).returncode == 0:
            return base
    pytest.skip("no base image to build on: make one with docker/make-base.sh (root, debootstrap)")


@pytest.fixture(scope="module")
def image(base_image) -> dict:
    """The image built from the working tree: {"base", "build_s", "size_bytes"}."""
    build = ["build", "--pull=never", "-f", str(DOCKER / "Dockerfile"),
             "--build-arg", f"PYTHON_IMAGE={base_image}", "-t", IMAGE]
    bundle = host_ca_bundle()
    if bundle is not None:
        build += ["-v", f"{bundle.resolve()}:/run/pip-ca.pem:ro", "--build-arg", "PIP_CERT=/run/pip-ca.pem"]
    start = time.monotonic()
    podman(*build, str(ROOT), timeout=BUILD_TIMEOUT_S)
    build_s = time.monotonic() - start
    size = json.loads(podman("image", "inspect", IMAGE).stdout)[0]["Size"]
    return {"base": base_image, "build_s": build_s, "size_bytes": size}


def test_the_image_builds_and_runs_camnet(image, capsys):
    done = podman("run", "--rm", *run_flags(), IMAGE, "--version")
    assert done.stdout.split() == ["camnet", version("camnet")]
    # The compose file's secrets are bind-mounted files that this user must be able to read.
    who = podman("run", "--rm", *run_flags(), "--entrypoint", "id", IMAGE, "-u").stdout.strip()
    assert who == "1000"
    podman_version = podman("--version").stdout.split()[-1]
    with capsys.disabled():
        print(f"\nimage {IMAGE} built with Podman {podman_version} on {image['base']} in "
              f"{image['build_s']:.0f} s, {image['size_bytes'] / 1e9:.2f} GB; "
              f"`camnet --version` in it: {done.stdout.strip()}")


def test_up_finds_its_built_in_rig_in_the_image(image):
    # In the image camnet is an installed wheel, with no source tree beside it.
    where = podman("run", "--rm", *run_flags(), "--entrypoint", "python", IMAGE, "-c",
                   "import camnet.commands.up as up; rig = up.default_rig(); "
                   "print(rig); print(rig.read_text(), end='')")
    path, _, text = where.stdout.partition("\n")
    assert path.startswith("/opt/camnet/lib/") and path.endswith("/site-packages/camnet/rigs/sim.yaml"), path
    assert text == (ROOT / "config" / "sim.yaml").read_text()
    done = podman("run", "--rm", *run_flags(), IMAGE, "up", "--duration-s", "1", check=False, timeout=120)
    # It loads the rig and starts its nodes; in a second they calibrate nothing (exit 2).
    assert "camnet up: rig 'sim', 4 cameras" in done.stdout, done.stdout + done.stderr
    assert done.returncode == 2 and "no calibration in 1 s" in done.stderr, done.stdout + done.stderr


def secret_mounts(services: list[dict], compose: dict, secrets_dir: Path) -> list[str]:
    """`-v` flags for the secrets compose mounts into `services`, taken from `secrets_dir`
    (`camnet secure init`'s output), each once."""
    names = sorted({name for service in services for name in service["secrets"]})
    return [flag for name in names
            for flag in ("-v", f"{secrets_dir / Path(compose['secrets'][name]['file']).name}:/run/secrets/{name}:ro")]


def secure_init(rig_path: Path, secrets_dir: Path) -> None:
    """The rig's secrets, as docker/README.md makes them, owned by the containers' user."""
    done = subprocess.run([sys.executable, "-m", "camnet.cli", "secure", "init", str(secrets_dir),
                           "--rig", str(rig_path), "--router-host", ROUTER_HOST],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
    files = sorted(secrets_dir.iterdir())
    if os.geteuid() == 0:
        for path in files:
            os.chown(path, CONTAINER_UID, -1)
    else:  # rootless Podman: the containers' uid 1000 is one of this user's sub-uids
        podman("unshare", "chown", str(CONTAINER_UID), *map(str, files))


class Lines:
    """The lines of a process's stdout, read by a thread so that waiting has a deadline."""

    def __init__(self, stream) -> None:
        self.seen: list[str] = []
        self._queue: queue.Queue[str | None] = queue.Queue()
        threading.Thread(target=self._read, args=(stream,), daemon=True).start()

    def _read(self, stream) -> None:
        for line in stream:
            self._queue.put(line.rstrip("\n"))
        self._queue.put(None)

    def wait_for(self, predicate, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            try:
                line = self._queue.get(timeout=min(1.0, max(0.0, deadline - time.monotonic())))
            except queue.Empty:
                continue
            if line is None:
                return False
            self.seen.append(line)
            if predicate(self.seen):
                return True
        return False

    def rest(self, timeout_s: float) -> None:
        self.wait_for(lambda _: False, timeout_s)


def solve_lines(lines: list[str]) -> list[str]:
    return [line for line in lines if " solve " in line]


def test_a_router_container_and_a_rig_container_calibrate(image, tmp_path, capsys):
    compose = load_compose()
    services = camnet_services(compose)
    rig_path = Path(rig_file(tmp_path, 4))
    rig_path.chmod(0o644)
    secrets_dir = tmp_path / "secrets"
    secure_init(rig_path, secrets_dir)
    out = tmp_path / "out"
    out.mkdir()
    out.chmod(0o777)  # the image's user (uid 1000) writes the calibration and the run's logs here

    router_service = services["router"]
    assert service_argv(router_service) == ["router", "--secure", "/run/secrets"]
    # `camnet up` runs every node of the machine: it needs the files of all their services.
    up_services = [s for s in services.values() if COMMAND_IDENTITY[service_argv(s)[0]] in UP_IDENTITIES]
    assert {COMMAND_IDENTITY[service_argv(s)[0]] for s in up_services} == UP_IDENTITIES

    name = f"camnet-test-{uuid.uuid4().hex[:8]}"
    router_name, rig_name = f"{name}-router", f"{name}-rig"
    podman("network", "create", "--internal", name)
    rig = None
    lines = None
    try:
        podman("run", "-d", "--name", router_name, "--network", name, *run_flags(),
               *secret_mounts([router_service], compose, secrets_dir), IMAGE, *service_argv(router_service))
        router_ip = podman("inspect", router_name, "--format",
                           f"{{{{(index .NetworkSettings.Networks \"{name}\").IPAddress}}}}").stdout.strip()
        assert router_ip, "the router container has no address on the network"

        rig = subprocess.Popen(
            [PODMAN, *podman_flags(), "run", "--rm", "--name", rig_name, "--network", name,
             "--add-host", f"{ROUTER_HOST}:{router_ip}", *run_flags(),
             *secret_mounts(up_services, compose, secrets_dir),
             "-v", f"{rig_path}:/etc/camnet/rig.yaml:ro", "-v", f"{out}:/out",
             IMAGE, "up", "/etc/camnet/rig.yaml", "--forever", "--run-dir", "/out/run",
             "-o", "/out/calibration.json", "--secure", "/run/secrets"],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        lines = Lines(rig.stdout)
        calibrated = lines.wait_for(lambda seen: len(solve_lines(seen)) >= SOLVES, timeout_s=300)
        assert calibrated, (f"no calibration from the rig's containers in 300 s:\n{tail(lines.seen)}"
                            f"{node_logs(out / 'run')}\nrouter:\n{router_log(router_name)[-3000:]}")
        # SIGTERM to `camnet up` (the container's first process): it stops its nodes, writes
        # the last calibration and prints it.
        podman("stop", "-t", "60", rig_name, timeout=90)
        assert rig.wait(timeout=60) == 0, tail(lines.seen)
        lines.rest(timeout_s=5)
        log = router_log(router_name)
    finally:
        if rig is not None and rig.poll() is None:
            podman("rm", "-f", "-v", "-t", "0", rig_name, check=False)
            rig.wait(timeout=60)
        podman("rm", "-f", "-v", "-t", "0", router_name, check=False)
        podman("network", "rm", "-f", name, check=False)

    # The router admitted each node by its own certificate, and no one without an identity.
    for identity in UP_IDENTITIES:
        assert f"admitted the {identity} (camnet-{identity})" in log, log[-3000:]
    assert "names no camnet identity" not in log, log[-3000:]
    cal = parse_calibration(json.loads((out / "calibration.json").read_text()))
    comparison = compare_cameras(cal, load_rig(rig_path).simulated_truth())
    assert len(cal.cameras) == 4
    # A real calibration, not its accuracy (tests/test_network.py holds that): within 1%.
    assert abs(comparison.scale_rel) < 0.01, "\n".join(lines.seen)
    assert max(abs(e.focal_rel) for e in comparison.cameras) < 0.01, "\n".join(lines.seen)
    with capsys.disabled():
        print(f"\ncalibration produced in containers (router {router_name} with `camnet router --secure`, "
              f"`camnet up --secure` in {rig_name}, TLS with a certificate per node on Podman network {name}): "
              f"{solve_lines(lines.seen)[-1].strip()}; final scale error {100 * comparison.scale_rel:+.3f}%")


def tail(lines: list[str], n: int = 30) -> str:
    return "\n".join(lines[-n:])


def node_logs(run_dir: Path) -> str:
    return "".join(f"\n{path.name}:\n{path.read_text(errors='replace')[-1500:]}"
                   for path in sorted(run_dir.glob("**/*.log")))


def router_log(container: str) -> str:
    done = podman("logs", container, check=False)
    return done.stdout + done.stderr
