"""The docker deployment without a Docker engine: the compose file is consistent with the
camnet commands, the image recipe and the secured rig's files: every service joins with its
own identity from `camnet secure init` output (what those files admit and refuse on loopback
is tests/test_security.py)."""

from __future__ import annotations

import json
import re
import shlex
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import yaml

from camnet.bus.security import COMMAND_IDENTITY, ROUTER
from camnet.bus.session import BusOptions, make_config

ROOT = Path(__file__).resolve().parents[1]
DOCKER = ROOT / "docker"
NODE_SERVICES = ("router", "matcher", "calibrator", "recorder", "status")
SECRETS = "/run/secrets"
# `${NAME:-default}`: every setting of the compose file has a default.
_VARIABLE = re.compile(r"\$\{(\w+)(:-([^}]*))?\}")


def load_compose(env: dict[str, str] | None = None) -> dict:
    """docker/compose.yaml as `docker compose config` would see it with `env` set."""
    env = env or {}
    text = (DOCKER / "compose.yaml").read_text()
    return yaml.safe_load(_VARIABLE.sub(lambda m: env.get(m[1], m[3] or ""), text))


def camnet_services(compose: dict) -> dict[str, dict]:
    return dict(compose["services"])


def service_argv(service: dict) -> list[str]:
    command = service["command"]
    return shlex.split(command) if isinstance(command, str) else list(command)


def driver_services(compose: dict, profile: str = "cameras") -> dict[str, dict]:
    """The driver services of `profile`: one per camera in `cameras`, one per camera host in `hosts`."""
    return {name: s for name, s in camnet_services(compose).items()
            if service_argv(s)[0] == "driver" and profile in s["profiles"]}


def option_values(argv: list[str], option: str) -> list[str]:
    return [argv[i + 1] for i, arg in enumerate(argv[:-1]) if arg == option]


def config_source(compose: dict, service: dict, target: str) -> Path:
    """The host file that `service` sees at `target` through a compose config."""
    for ref in service["configs"]:
        if ref["target"] == target:
            return DOCKER / compose["configs"][ref["source"]]["file"]
    raise AssertionError(f"no config mounted at {target}")


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
    assert service_argv(services["router"])[:3] == ["router", "--secure", SECRETS]
    assert set(NODE_SERVICES) <= set(services)
    rig_file = config_source(compose, services["matcher"], "/etc/camnet/rig.yaml")
    rig = load_rig(rig_file)
    drivers = {}
    for name, service in driver_services(compose).items():
        argv = service_argv(service)
        [camera_id] = option_values(argv, "--camera")
        entry = rig.camera(camera_id)
        assert entry.driver == argv[1], f"{name}: rig says driver {entry.driver}"
        drivers[entry.id] = name
    every_driver = {n for n, s in camnet_services(compose).items() if service_argv(s)[0] == "driver"}
    assert every_driver == set(drivers.values()) | set(driver_services(compose, "hosts")), \
        "a driver service in neither the cameras nor the hosts profile"
    assert sorted(drivers) == sorted(c.id for c in rig.cameras), "a camera without a driver service"
    recorder = service_argv(services["recorder"])
    assert option_value(recorder, "--rig") == option_value(service_argv(services["status"]), "--rig") == rig.name
    assert option_value(recorder, "-o").startswith("/sessions/")
    assert services["recorder"]["volumes"] == ["sessions:/sessions"]
    calibrator = service_argv(services["calibrator"])
    assert option_value(calibrator, "--state").startswith("/state/")
    assert services["calibrator"]["volumes"] == ["calibrator-state:/state"]


def test_hosts_profile_runs_every_camera_of_its_rig_once_on_four_hosts_with_features():
    """Profile `hosts`: config/hosts16.yaml's 16 cameras, four per camera host, each host one process
    detecting its cameras' features (what benchmarks/bench_hosts.py runs on one machine)."""
    from camnet.cli import build_parser
    from camnet.io.rig import load_rig

    compose = load_compose({"CAMNET_RIG": "../config/hosts16.yaml"})
    rig = load_rig(config_source(compose, compose["services"]["matcher"], "/etc/camnet/rig.yaml"))
    hosts = driver_services(compose, "hosts")
    assert len(hosts) == 4 and len(rig.cameras) == 16
    placed: list[str] = []
    for name, service in hosts.items():
        argv = service_argv(service)
        args = build_parser().parse_args(argv)
        assert args.features and len(args.camera) == 4, name
        assert all(rig.camera(c).driver == args.driver for c in args.camera), name
        assert service["profiles"] == ["hosts"], f"{name} would also start in another profile"
        placed += args.camera
    assert sorted(placed) == sorted(c.id for c in rig.cameras), "a camera on no host, or on two"
    assert "hosts16" in (DOCKER / "README.md").read_text()


def test_compose_settings_change_what_they_name():
    compose = load_compose({"CAMNET_RIG": "/srv/lab.yaml", "CAMNET_RIG_NAME": "lab",
                            "CAMNET_IMAGE": "registry.example/camnet:1", "ZENOH_VERSION": "9.9.9"})
    assert compose["configs"]["rig"]["file"] == "/srv/lab.yaml"
    assert option_value(service_argv(compose["services"]["recorder"]), "--rig") == "lab"
    for name, service in camnet_services(compose).items():
        assert service["image"] == "registry.example/camnet:1", name
        assert service["build"]["args"]["ZENOH_VERSION"] == "9.9.9", name


def identity_files(identity: str) -> set[str]:
    return {"secure.json", "ca.pem", f"{identity}.pem", f"{identity}-key.pem"}


def test_every_service_joins_the_secured_rig_with_its_own_identity_only():
    compose = load_compose()
    for name, service in camnet_services(compose).items():
        argv = service_argv(service)
        assert service["network_mode"] == "host", name
        assert option_value(argv, "--secure") == SECRETS, name
        for flag in ("--connect", "--listen", "--zenoh-config"):
            assert flag not in argv, f"{name}: {flag} (the router's address is in secure.json)"
        # A host gets the key of the node kinds it runs, and no other.
        assert set(service["secrets"]) == identity_files(COMMAND_IDENTITY[argv[0]]), name
        assert set(service["secrets"]) <= set(compose["secrets"]), name
    assert "7447" in (DOCKER / "README.md").read_text()


def test_compose_files_exist():
    compose = load_compose()
    for name, config in compose["configs"].items():
        assert (DOCKER / config["file"]).is_file(), f"config {name}: {config['file']} missing"
    for name, secret in compose["secrets"].items():
        # Secrets are made per deployment, never committed: they come from camnet secure init.
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
    # Router and nodes run one image, with this Zenoh.
    assert {s["image"] for s in compose["services"].values()} == {"camnet:latest"}
    assert {s["build"]["args"]["ZENOH_VERSION"] for s in compose["services"].values()} == {pinned}
    # The settings are tested here with the installed Zenoh: it must be the version deployed.
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


@pytest.fixture(scope="module")
def secrets_dir(tmp_path_factory) -> Path:
    """`camnet secure init` output for the compose file's default rig."""
    if shutil.which("openssl") is None:
        pytest.skip("camnet secure init needs the openssl CLI")
    out = tmp_path_factory.mktemp("docker") / "secrets"
    rig = config_source(load_compose(), load_compose()["services"]["matcher"], "/etc/camnet/rig.yaml")
    done = subprocess.run([sys.executable, "-m", "camnet.cli", "secure", "init", str(out), "--rig", str(rig)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return out


def test_secure_init_writes_every_secret_compose_mounts(secrets_dir):
    compose = load_compose()
    written = {p.name for p in secrets_dir.iterdir()}
    wanted = {Path(s["file"]).name for s in compose["secrets"].values()}
    assert {Path(s["file"]).parent.name for s in compose["secrets"].values()} == {"secrets"}
    assert wanted <= written
    # The CA's key is mounted nowhere; no service replays.
    assert written - wanted == {"ca-key.pem", "replayer.pem", "replayer-key.pem"}
    assert json.loads((secrets_dir / "secure.json").read_text())["rig"] == "sim"


def test_each_service_makes_its_zenoh_config_from_its_mounted_files_alone(secrets_dir, tmp_path):
    compose = load_compose()
    for name, service in camnet_services(compose).items():
        # The service's /run/secrets, as compose mounts it: its own files, no more.
        run_secrets = tmp_path / name
        run_secrets.mkdir()
        for secret in service["secrets"]:
            shutil.copy(secrets_dir / Path(compose["secrets"][secret]["file"]).name, run_secrets / secret)
        identity = COMMAND_IDENTITY[service_argv(service)[0]]
        config = make_config(BusOptions(secure=str(run_secrets), identity=identity,
                                        mode="router" if identity == ROUTER else "peer"))
        assert json.loads(config.get_json("transport/link/protocols")) == ["tls"], name
        if identity == ROUTER:
            assert json.loads(config.get_json("access_control/enabled")) is True
            [endpoint] = json.loads(config.get_json("listen/endpoints"))
        else:
            assert json.loads(config.get_json("mode")) == "client", name
            [endpoint] = json.loads(config.get_json("connect/endpoints"))
        assert endpoint.startswith("tls/") and endpoint.endswith(":7447"), (name, endpoint)
