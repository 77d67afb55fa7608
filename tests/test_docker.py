"""The docker deployment without a Docker engine: the compose file is consistent with the
camnet commands, the image recipe and the Zenoh configs, and the configs' TLS and password
authentication really admit the deployment's nodes and refuse everyone else (Zenoh on
loopback, throwaway secrets from docker/make-certs.sh)."""

from __future__ import annotations

import json
import re
import shlex
import shutil
import subprocess
import sys
import textwrap
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
import yaml

from camnet.bus.session import BusOptions, make_config, open_session
from tests.conftest import free_port, matched_publisher, wait_for

ROOT = Path(__file__).resolve().parents[1]
DOCKER = ROOT / "docker"
MAKE_CERTS = DOCKER / "make-certs.sh"
NODE_SERVICES = ("matcher", "calibrator", "recorder")
# `${NAME:-default}`: every setting of the compose file has a default.
_VARIABLE = re.compile(r"\$\{(\w+)(:-([^}]*))?\}")

OPENSSL_MISSING = shutil.which("openssl") is None or shutil.which("bash") is None
needs_openssl = pytest.mark.skipif(OPENSSL_MISSING, reason="docker/make-certs.sh needs bash and the openssl CLI")


def load_compose(env: dict[str, str] | None = None) -> dict:
    """docker/compose.yaml as `docker compose config` would see it with `env` set."""
    env = env or {}
    text = (DOCKER / "compose.yaml").read_text()
    return yaml.safe_load(_VARIABLE.sub(lambda m: env.get(m[1], m[3] or ""), text))


def camnet_services(compose: dict) -> dict[str, dict]:
    return {name: s for name, s in compose["services"].items() if name != "router"}


def service_argv(service: dict) -> list[str]:
    command = service["command"]
    return shlex.split(command) if isinstance(command, str) else list(command)


def driver_services(compose: dict) -> dict[str, dict]:
    return {name: s for name, s in camnet_services(compose).items()
            if service_argv(s)[0] == "driver"}


def config_source(compose: dict, service: dict, target: str) -> Path:
    """The host file that `service` sees at `target` through a compose config."""
    for ref in service["configs"]:
        if ref["target"] == target:
            return DOCKER / compose["configs"][ref["source"]]["file"]
    raise AssertionError(f"no config mounted at {target}")


def secret_paths(text: str) -> set[str]:
    return set(re.findall(r"/run/secrets/[\w.-]+", text))


def option_value(argv: list[str], option: str) -> str:
    return argv[argv.index(option) + 1]


# --- compose file -----------------------------------------------------------------------


def test_compose_settings_all_have_defaults():
    text = (DOCKER / "compose.yaml").read_text()
    variables = list(_VARIABLE.finditer(text))
    assert variables, "compose.yaml has no settings?"
    assert all(m[2] for m in variables), [m[0] for m in variables if not m[2]]
    assert "$" not in _VARIABLE.sub("", text), "a variable that is not ${NAME:-default}"


def test_compose_has_every_node_of_the_rig():
    from camnet.io.rig import load_rig

    compose = load_compose()
    services = compose["services"]
    assert services["router"]["image"].startswith("eclipse/zenoh:")
    assert set(NODE_SERVICES) <= set(services)
    rig_file = config_source(compose, services["matcher"], "/etc/camnet/rig.yaml")
    rig = load_rig(rig_file)
    drivers = {}
    for name, service in driver_services(compose).items():
        argv = service_argv(service)
        entry = rig.camera(option_value(argv, "--camera"))
        assert entry.driver == argv[1], f"{name}: rig says driver {entry.driver}"
        assert "cameras" in service["profiles"], f"{name} is not in the cameras profile"
        drivers[entry.id] = name
    assert sorted(drivers) == sorted(c.id for c in rig.cameras), "a camera without a driver service"
    recorder = service_argv(services["recorder"])
    assert option_value(recorder, "--rig") == rig.name
    assert option_value(recorder, "-o").startswith("/sessions/")
    assert services["recorder"]["volumes"] == ["sessions:/sessions"]
    calibrator = service_argv(services["calibrator"])
    assert option_value(calibrator, "--state").startswith("/state/")
    assert services["calibrator"]["volumes"] == ["calibrator-state:/state"]


def test_compose_settings_change_what_they_name():
    compose = load_compose({"CAMNET_RIG": "/srv/lab.yaml", "CAMNET_RIG_NAME": "lab",
                            "CAMNET_IMAGE": "registry.example/camnet:1", "ZENOH_VERSION": "9.9.9"})
    assert compose["configs"]["rig"]["file"] == "/srv/lab.yaml"
    assert option_value(service_argv(compose["services"]["recorder"]), "--rig") == "lab"
    assert compose["services"]["router"]["image"] == "eclipse/zenoh:9.9.9"
    for name, service in camnet_services(compose).items():
        assert service["image"] == "registry.example/camnet:1", name
        assert service["build"]["args"]["ZENOH_VERSION"] == "9.9.9", name


def test_every_service_can_reach_the_router_over_tls():
    compose = load_compose()
    router = compose["services"]["router"]
    router_config = config_source(compose, router, option_value(router["command"], "--config"))
    router_text = router_config.read_text()
    node_text = (DOCKER / "zenoh" / "node.json5").read_text()
    # Every secret a config names is mounted where it looks for it, and exists in the list.
    assert secret_paths(router_text) == {f"/run/secrets/{s}" for s in router["secrets"]}
    assert set(router["secrets"]) <= set(compose["secrets"])
    for name, service in camnet_services(compose).items():
        assert service["network_mode"] == "host", name
        mounted = {f"/run/secrets/{s}" for s in service["secrets"]}
        zenoh_config = option_value(service_argv(service), "--zenoh-config")
        assert zenoh_config in mounted, f"{name}: {zenoh_config} is not mounted"
        assert secret_paths(node_text) <= mounted, name
        assert "--connect" not in service_argv(service), f"{name}: the router address is in node.json5"
    listen = make_config(BusOptions(zenoh_config=str(router_config), mode="router"))
    connect = make_config(BusOptions(zenoh_config=str(DOCKER / "zenoh" / "node.json5")))
    [listen_endpoint] = json.loads(listen.get_json("listen/endpoints"))
    [connect_endpoint] = json.loads(connect.get_json("connect/endpoints"))
    assert listen_endpoint.startswith("tls/") and connect_endpoint.startswith("tls/")
    # A client: the router is the nodes' only link, so every link is TLS with a password.
    assert json.loads(connect.get_json("mode")) == "client"
    assert listen_endpoint.rsplit(":", 1)[1] == connect_endpoint.rsplit(":", 1)[1] == "7447"
    assert "7447" in (DOCKER / "README.md").read_text()


def test_compose_files_exist():
    compose = load_compose()
    for name, config in compose["configs"].items():
        assert (DOCKER / config["file"]).is_file(), f"config {name}: {config['file']} missing"
    for name, secret in compose["secrets"].items():
        # Secrets are made per deployment, never committed: they must come from make-certs.sh.
        assert secret["file"].startswith("./secrets/"), name
    assert "secrets/" in (DOCKER / ".gitignore").read_text().split()


def _all_service_commands() -> list[str]:
    return sorted({service_argv(s)[0] for s in camnet_services(load_compose()).values()})


@pytest.mark.parametrize("command", _all_service_commands())
def test_service_command_exists(command):
    done = subprocess.run([sys.executable, "-m", "camnet", command, "--help"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, f"camnet {command} --help: {done.stderr.strip()[-500:]}"


@pytest.mark.parametrize("service", sorted(camnet_services(load_compose())))
def test_service_command_line_parses(service):
    from camnet.cli import COMMANDS, build_parser

    argv = service_argv(load_compose()["services"][service])
    assert argv[0] in COMMANDS, f"{service}: camnet has no command {argv[0]!r}"
    try:
        build_parser().parse_args(argv)
    except SystemExit as exc:
        pytest.fail(f"{service}: camnet {' '.join(argv)} does not parse (exit {exc.code})")


def test_readme_camera_block_adds_a_camera():
    """The five lines docker/README.md tells users to paste make a working driver service."""
    from camnet.cli import build_parser

    readme = (DOCKER / "README.md").read_text()
    [block] = re.findall(r"```yaml\n(.*?)```", readme, flags=re.DOTALL)
    block = textwrap.dedent(block)
    assert len(block.strip().splitlines()) == 5
    text = (DOCKER / "compose.yaml").read_text().replace("\nservices:\n",
                                                         "\nservices:\n" + textwrap.indent(block, "  "))
    compose = yaml.safe_load(_VARIABLE.sub(lambda m: m[3] or "", text))
    [(name, service)] = [(n, s) for n, s in driver_services(compose).items()
                         if n not in driver_services(load_compose())]
    assert "cameras" in service["profiles"] and service["network_mode"] == "host", name
    assert service["secrets"] == load_compose()["services"]["cam-left"]["secrets"]
    build_parser().parse_args(service_argv(service))


# --- image ------------------------------------------------------------------------------


def dockerfile_stages() -> list[str]:
    text = (DOCKER / "Dockerfile").read_text().replace("\\\n", " ")
    return re.split(r"^FROM ", text, flags=re.MULTILINE)[1:]


def apt_packages(stage: str) -> set[str]:
    packages = set()
    for m in re.finditer(r"apt-get install ([^&]*)", stage):
        packages |= {w for w in m[1].split() if not w.startswith(("-", "$"))}
    return packages


def test_image_installs_what_ci_installs():
    build, runtime = dockerfile_stages()
    ci = apt_packages((ROOT / ".ci" / "run").read_text().replace("\\\n", " "))
    # PyGObject's build needs (as in CI), and the Aravis typelib at run time.
    assert {"libgirepository1.0-dev", "libcairo2-dev", "pkg-config"} <= ci & apt_packages(build)
    assert "gir1.2-aravis-0.8" in ci & apt_packages(runtime)
    assert "aravis-tools-cli" in apt_packages(runtime)
    assert not {p for p in apt_packages(runtime) if p.endswith("-dev")}, "build packages at run time"


def test_image_installs_camnet_with_the_aravis_extra_and_the_routers_zenoh():
    import tomllib
    from importlib.metadata import version

    build, runtime = dockerfile_stages()
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert "aravis" in project["optional-dependencies"]
    assert "['optional-dependencies']['aravis']" in build
    assert re.search(r"^USER (?!root)\w+", runtime, flags=re.MULTILINE), "the image runs as root"
    assert 'ENTRYPOINT ["camnet"]' in runtime
    [pinned] = re.findall(r"^ARG ZENOH_VERSION=(\S+)", build, flags=re.MULTILINE)
    compose = load_compose()
    assert compose["services"]["router"]["image"] == f"eclipse/zenoh:{pinned}"
    # The configs are tested here with the installed Zenoh: it must be the version deployed.
    installed = version("eclipse-zenoh")
    assert installed.split(".")[:2] == pinned.split(".")[:2], \
        f"installed eclipse-zenoh {installed}, the image pins {pinned}: update ZENOH_VERSION"


def test_build_context_holds_the_sources_and_no_secrets():
    patterns = [line.strip() for line in (ROOT / ".dockerignore").read_text().splitlines()
                if line.strip() and not line.startswith("#")]
    assert patterns[0] == "*", ".dockerignore must start by excluding everything"
    allowed = {p.lstrip("!").rstrip("/") for p in patterns if p.startswith("!")}
    copied = set()
    for stage in dockerfile_stages():
        for m in re.finditer(r"^COPY (?!--from)(.+) \S+$", stage, flags=re.MULTILINE):
            copied |= set(m[1].split())
    assert copied and copied <= allowed, f"COPY of files outside the build context: {copied - allowed}"
    assert not any(a == "docker" or a.startswith("docker/") for a in allowed)


# --- secrets ----------------------------------------------------------------------------


def make_certs(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", str(MAKE_CERTS), *args], capture_output=True, text=True,
                          timeout=60)


@pytest.fixture(scope="module")
def secrets_dir(tmp_path_factory) -> Path:
    if OPENSSL_MISSING:
        pytest.skip("docker/make-certs.sh needs bash and the openssl CLI")
    out = tmp_path_factory.mktemp("secrets")
    done = make_certs("-o", str(out), "localhost")
    assert done.returncode == 0, done.stderr
    return out


def test_make_certs_writes_every_secret_compose_mounts(secrets_dir):
    compose = load_compose()
    written = {p.name for p in secrets_dir.iterdir()}
    wanted = {Path(s["file"]).name for s in compose["secrets"].values()}
    assert wanted <= written
    assert written - wanted == {"ca-key.pem"}, "the CA key must not be mounted anywhere"
    assert secrets_dir.stat().st_mode & 0o077 == 0
    for private in ("ca-key.pem", "router-key.pem", "passwords.txt"):
        assert (secrets_dir / private).stat().st_mode & 0o077 == 0, private
    [line] = (secrets_dir / "passwords.txt").read_text().splitlines()
    user, password = line.split(":")
    node = make_config(BusOptions(zenoh_config=str(secrets_dir / "node.json5")))
    assert json.loads(node.get_json("transport/auth/usrpwd/user")) == user
    assert json.loads(node.get_json("transport/auth/usrpwd/password")) == password
    assert len(password) >= 24


@needs_openssl
def test_make_certs_names_the_router_host_and_refuses_bad_calls(tmp_path):
    out = tmp_path / "s"
    done = make_certs("-o", str(out), "rig-router.lan", "10.0.0.5")
    assert done.returncode == 0, done.stderr
    sans = subprocess.run(["openssl", "x509", "-in", str(out / "router.pem"), "-noout", "-ext",
                           "subjectAltName"], capture_output=True, text=True, check=True).stdout
    for name in ("DNS:rig-router.lan", "IP Address:10.0.0.5", "DNS:localhost", "IP Address:127.0.0.1"):
        assert name in sans
    verify = subprocess.run(["openssl", "verify", "-CAfile", str(out / "ca.pem"), str(out / "router.pem")],
                            capture_output=True, text=True)
    assert verify.returncode == 0, verify.stdout + verify.stderr
    node = make_config(BusOptions(zenoh_config=str(out / "node.json5")))
    assert json.loads(node.get_json("connect/endpoints")) == ["tls/rig-router.lan:7447"]

    before = (out / "passwords.txt").read_text()
    again = make_certs("-o", str(out), "other")
    assert again.returncode == 2 and "-f" in again.stderr and again.stderr.count("\n") == 1
    assert (out / "passwords.txt").read_text() == before
    missing = make_certs("-o", str(tmp_path / "t"))
    assert missing.returncode == 2 and "ROUTER_HOST" in missing.stderr
    assert make_certs("-f", "-o", str(out), "other").returncode == 0
    assert (out / "passwords.txt").read_text() != before


# --- TLS and password authentication on loopback ------------------------------------------


def deployed_config(source: Path, secrets_dir: Path, tmp_path: Path) -> str:
    """`source` with /run/secrets/NAME replaced by the file compose would mount there."""
    compose = load_compose()
    text = source.read_text()
    for name, secret in compose["secrets"].items():
        text = text.replace(f"/run/secrets/{name}", str(secrets_dir / Path(secret["file"]).name))
    assert not secret_paths(text), f"{source.name} names secrets compose does not mount"
    path = tmp_path / source.name
    path.write_text(text)
    return str(path)


def open_node(config_path: str, endpoint: str, changes: dict | None = None, *,
              timeout_ms: int | None = 5000):
    """A node session from `config_path` connected to `endpoint`, with `changes` applied; or
    the error that kept it from opening. Nodes wait for the router forever (timeout_ms: -1
    in node.json5); tests give up after `timeout_ms` (None: keep the file's)."""
    import zenoh

    config = make_config(BusOptions(zenoh_config=config_path, connect=(endpoint,)))
    if timeout_ms is not None:
        changes = {"connect/timeout_ms": timeout_ms, **(changes or {})}
    for key, value in (changes or {}).items():
        config.insert_json5(key, json.dumps(value))
    try:
        return zenoh.open(config)
    except zenoh.ZError as exc:
        return exc


def close_all(*sessions) -> None:
    for session in sessions:
        if session is not None and not isinstance(session, Exception):
            session.close()


@pytest.fixture
def secured_router(secrets_dir, tmp_path):
    """(router session, node config path, router port): the committed router config with the
    deployment's secrets, listening on a free loopback port."""
    port = free_port()
    router_config = deployed_config(DOCKER / "zenoh" / "router.json5", secrets_dir, tmp_path)
    node_config = deployed_config(secrets_dir / "node.json5", secrets_dir, tmp_path)
    router = open_session(BusOptions(zenoh_config=router_config, mode="router",
                                     listen=(f"tls/127.0.0.1:{port}",)))
    try:
        yield router, node_config, port
    finally:
        router.close()


def test_tls_with_password_admits_the_nodes(secured_router):
    router, node_config, port = secured_router
    # localhost, as on a single host: the name is checked against the router's certificate.
    a = open_node(node_config, f"tls/localhost:{port}")
    b = open_node(node_config, f"tls/localhost:{port}")
    try:
        assert not isinstance(a, Exception) and not isinstance(b, Exception), (a, b)
        assert wait_for(lambda: list(a.info.routers_zid()) and list(b.info.routers_zid()), 10.0)
        got = []
        a.declare_subscriber("camnet/test/**", lambda s: got.append(bytes(s.payload.to_bytes())))
        # Nodes do not listen: the sample can only go through the router.
        matched_publisher(b, "camnet/test/x", 10.0).put(b"hello")
        assert wait_for(lambda: got == [b"hello"], 5.0)
    finally:
        close_all(a, b)


def test_tls_with_password_refuses_everyone_else(secured_router):
    router, node_config, port = secured_router
    good_endpoint = f"tls/localhost:{port}"
    intruders = {
        "no credentials": (good_endpoint, {"transport/auth/usrpwd/user": None,
                                           "transport/auth/usrpwd/password": None}),
        "wrong password": (good_endpoint, {"transport/auth/usrpwd/password": "guess"}),
        "unknown user": (good_endpoint, {"transport/auth/usrpwd/user": "mallory"}),
        # Without the deployment's CA the router's certificate is not trusted.
        "no CA": (good_endpoint, {"transport/link/tls/root_ca_certificate": None}),
        "plain tcp": (f"tcp/127.0.0.1:{port}", {"transport/link/protocols": None}),
    }
    good = open_node(node_config, good_endpoint)
    witness = open_node(node_config, good_endpoint)
    with ThreadPoolExecutor(len(intruders)) as pool:  # each may wait out its timeout
        futures = {name: pool.submit(open_node, node_config, endpoint, changes)
                   for name, (endpoint, changes) in intruders.items()}
    sessions = {name: future.result() for name, future in futures.items()}
    try:
        assert not isinstance(good, Exception) and not isinstance(witness, Exception), (good, witness)
        got = []
        good.declare_subscriber("camnet/test/**", lambda s: got.append(bytes(s.payload.to_bytes())))
        witness_publisher = matched_publisher(witness, "camnet/test/witness", 10.0)
        time.sleep(2.0)  # the intruders had longer than the good nodes needed
        for name, session in sessions.items():
            if isinstance(session, Exception):
                continue  # refused at open
            assert list(session.info.routers_zid()) == [], f"{name}: the router let it in"
            session.put("camnet/test/intruder", name.encode())
        # Sent after the intruders' samples, along the path theirs would take.
        witness_publisher.put(b"witness")
        assert wait_for(lambda: b"witness" in got, 5.0)
        time.sleep(0.5)
        assert got == [b"witness"], f"intruders' samples arrived: {got}"
    finally:
        close_all(good, witness, *sessions.values())


def test_router_config_refuses_plain_tcp(secrets_dir, tmp_path):
    from camnet.errors import CamnetError

    router_config = deployed_config(DOCKER / "zenoh" / "router.json5", secrets_dir, tmp_path)
    with pytest.raises(CamnetError, match="Unsupported protocol: tcp"):
        open_session(BusOptions(zenoh_config=router_config, mode="router",
                                listen=(f"tcp/127.0.0.1:{free_port()}",))).close()


def test_a_node_started_before_the_router_waits_for_it(secrets_dir, tmp_path):
    port = free_port()
    router_config = deployed_config(DOCKER / "zenoh" / "router.json5", secrets_dir, tmp_path)
    node_config = deployed_config(secrets_dir / "node.json5", secrets_dir, tmp_path)
    opened = []
    # The file's own timeout (wait forever): a daemon thread, so a bug fails the test below
    # instead of hanging it.
    waiting = threading.Thread(daemon=True, target=lambda: opened.append(
        open_node(node_config, f"tls/localhost:{port}", timeout_ms=None)))
    waiting.start()
    time.sleep(1.5)
    assert not opened, f"the node gave up before the router came: {opened}"
    router = open_session(BusOptions(zenoh_config=router_config, mode="router",
                                     listen=(f"tls/127.0.0.1:{port}",)))
    try:
        waiting.join(timeout=15)
        assert opened, "the node did not connect to the router that came up"
        assert not isinstance(opened[0], Exception), opened[0]
        assert wait_for(lambda: list(opened[0].info.routers_zid()), 5.0)
    finally:
        close_all(*opened)
        router.close()


def test_nodes_refuse_a_router_of_another_deployment(secrets_dir, tmp_path):
    """A router with a certificate from another CA (and a dictionary holding the node's own
    password) does not get the node: the node checks the router, not only the reverse."""
    other = tmp_path / "other"
    assert make_certs("-o", str(other), "localhost").returncode == 0
    node_config = deployed_config(secrets_dir / "node.json5", secrets_dir, tmp_path)
    (tmp_path / "rogue").mkdir()
    rogue_config = deployed_config(DOCKER / "zenoh" / "router.json5", other, tmp_path / "rogue")
    shutil.copy(secrets_dir / "passwords.txt", other / "passwords.txt")
    port = free_port()
    rogue = open_session(BusOptions(zenoh_config=rogue_config, mode="router",
                                    listen=(f"tls/127.0.0.1:{port}",)))
    node = open_node(node_config, f"tls/localhost:{port}")
    try:
        assert isinstance(node, Exception) or not wait_for(lambda: list(node.info.routers_zid()), 2.0)
    finally:
        close_all(node)
        rogue.close()
