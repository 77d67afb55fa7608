"""Who may say what on a secured rig: Zenoh's own TLS, certificates and access control, configured.

A secured rig has one Zenoh router and every node is a Zenoh client of it:
every link is TLS, and each side proves who it is with a certificate from
the rig's own CA (mutual TLS). A node's certificate names its identity, its
node kind, in its common name (``camnet-driver``, ``camnet-matcher`` ...).
The router's access control (Zenoh's ACL, ``access_control`` in its config)
then admits each identity to the keys of its job only and refuses the rest:
a driver publishes frames and may not publish observations, only the
calibrator publishes the calibration, and a peer whose certificate names no
identity may do nothing at all. Zenoh does every check; this module only
writes its configuration.

`camnet secure init` (camnet.bus.certificates) writes a directory of secrets
for one rig; `--secure DIR` on a node reads it (`load_secure_dir`) and
`zenoh_settings` turns it into the Zenoh options of that node or router.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path

from camnet.bus import keys
from camnet.errors import InputError

log = logging.getLogger(__name__)

MANIFEST = "secure.json"
MANIFEST_FORMAT = "camnet.secure/1"
CA_CERTIFICATE = "ca.pem"
CA_PRIVATE_KEY = "ca-key.pem"
DEFAULT_PORT = 7447
CONNECT_TRY_MS = 10_000
ROUTER = "router"

# Which identity each camnet command uses: its node kind. `up` and `status` only watch.
COMMAND_IDENTITY = {
    "driver": "driver", "features": "driver", "matcher": "matcher", "calibrator": "calibrator", "record": "recorder",
    "replay": "replayer", "up": "observer", "status": "observer", "router": ROUTER,
}
IDENTITIES = ("driver", "matcher", "calibrator", "recorder", "replayer", "observer", ROUTER)


def common_name(identity: str) -> str:
    """The common name of `identity`'s certificate: what the router's ACL knows it by."""
    return f"camnet-{identity}"


@dataclass(frozen=True)
class Grants:
    """What one identity may do, as Zenoh key expressions per kind of action.

    A rule's key expression must include the one a node declares: a node
    that subscribes to ``camnet/sim/**`` needs a grant on ``camnet/sim/**``,
    not on each key below it (Zenoh's ACL does not match supersets).
    """

    publish: tuple[str, ...] = ()  # put samples
    subscribe: tuple[str, ...] = ()  # declare subscribers and receive samples
    serve: tuple[str, ...] = ()  # declare queryables, receive queries and reply
    ask: tuple[str, ...] = ()  # send queries and receive replies
    token: tuple[str, ...] = ()  # declare liveliness tokens
    watch: tuple[str, ...] = ()  # liveliness subscribers and queries, and the tokens they see


# Zenoh's ACL message types for each action, by direction as seen from the router: ingress is
# what the identity sends to the router, egress what the router sends on to it.
_ACTION_MESSAGES: dict[str, tuple[tuple[str, tuple[str, ...]], ...]] = {
    "publish": (("ingress", ("put",)),),
    "subscribe": (("ingress", ("declare_subscriber",)), ("egress", ("put",))),
    "serve": (("ingress", ("declare_queryable", "reply")), ("egress", ("query",))),
    "ask": (("ingress", ("query",)), ("egress", ("reply",))),
    "token": (("ingress", ("liveliness_token",)),),
    "watch": (("ingress", ("declare_liveliness_subscriber", "liveliness_query")),
              ("egress", ("liveliness_token",))),
}
# A client sends a sample only once it knows of a subscriber, and a query once it knows of a
# queryable. The subscribers it must learn of are any whose key expression intersects what it
# publishes (the recorder's camnet/<rig>/**, status's camnet/<rig>/nodes/*/*/stats), which a
# rule only covers by including them: publishers and askers learn of every one of the rig's.
# That says who listens, and lets no one say anything.
_LEARN_MESSAGES = {"publish": "declare_subscriber", "ask": "declare_queryable"}


def grants(rig: str) -> dict[str, Grants]:
    """What each node kind of `rig` may do: its job's keys, its own liveliness and statistics."""
    prefix = keys.rig_prefix(rig)
    frames, features = keys.all_frames(rig), keys.all_features(rig)
    observations, calibration, groundtruth = keys.observations(rig), keys.calibration(rig), keys.groundtruth(rig)
    calibrators = keys.all_calibrators(rig)  # a calibrator's token names its session (camnet.bus.source)

    def own(kind: str) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """(liveliness tokens, statistics) of the nodes of `kind`, whatever their ids."""
        return (f"{prefix}/nodes/{kind}/*",), (f"{prefix}/nodes/{kind}/*/stats",)

    def acks(kind: str) -> tuple[str, ...]:
        return (keys.lockstep_ack(rig, kind),)

    driver_tokens, driver_stats = own("driver")
    stage_tokens, stage_stats = own("features")  # `camnet features`: a node of kind features
    matcher_tokens, matcher_stats = own("matcher")
    calibrator_tokens, calibrator_stats = own("calibrator")
    recorder_tokens, recorder_stats = own("recorder")
    return {
        # The sim driver also publishes the simulation's ground truth, and answers for it. A camera's
        # feature stage runs on its host with the driver's identity: beside it, or on its frames; it
        # detects at the pace the matcher's statistics show (services/features.py).
        "driver": Grants(publish=(frames, features, groundtruth, *driver_stats, *stage_stats), serve=(groundtruth,),
                         subscribe=(frames, *matcher_stats), token=(*driver_tokens, *stage_tokens, features)),
        # A replayed camera is a driver to the rest of the rig (services/replayer.py); a lockstep
        # replay also announces its steps and waits for the acknowledgements.
        "replayer": Grants(publish=(frames, features, groundtruth, *driver_stats, keys.lockstep_step(rig)),
                           serve=(groundtruth,), token=(*driver_tokens, features),
                           subscribe=(keys.all_lockstep_acks(rig),), watch=(keys.all_lockstep_acks(rig),)),
        # The calibration: to choose the pairs it matches (camnet.matching.viewgraph), asked for at start, taken
        # only from a declared calibrator; the feature stages' tokens: a camera's features are taken only from a
        # stage declared for it.
        "matcher": Grants(subscribe=(frames, features, calibration, keys.lockstep_step(rig)),
                          ask=(calibration,),
                          publish=(observations, *matcher_stats, *acks("matcher")), serve=(observations,),
                          token=(*matcher_tokens, *acks("matcher")), watch=(features, calibrators)),
        # Frames only for showing them in Rerun beside the solve.
        "calibrator": Grants(subscribe=(observations, frames),
                             publish=(calibration, *calibrator_stats, *acks("calibrator")),
                             serve=(calibration,), token=(*calibrator_tokens, *acks("calibrator"), calibrators)),
        "recorder": Grants(subscribe=(f"{prefix}/**",), watch=(keys.all_nodes(rig), calibrators),
                           ask=(groundtruth, calibration), publish=recorder_stats, token=recorder_tokens),
        # `camnet up` and `camnet status`: they read, and publish nothing.
        "observer": Grants(subscribe=(calibration, observations, keys.all_node_stats(rig)),
                           watch=(keys.all_nodes(rig),), ask=(calibration,)),
    }


def _allow(rule_id: str, flow: str, messages: tuple[str, ...], key_exprs: tuple[str, ...]) -> dict:
    return {"id": rule_id, "permission": "allow", "flows": [flow], "messages": list(messages),
            "key_exprs": list(key_exprs)}


def _rules(identity: str, grant: Grants, rig: str) -> list[dict]:
    """Zenoh ACL rules (allow) for what `grant` lets `identity` do."""
    rules = []
    for action, directions in _ACTION_MESSAGES.items():
        key_exprs = getattr(grant, action)
        if not key_exprs:
            continue
        for flow, messages in directions:
            rules.append(_allow(f"{identity} {action} {flow}", flow, messages, key_exprs))
        if action in _LEARN_MESSAGES:
            rules.append(_allow(f"{identity} {action} learns", "egress", (_LEARN_MESSAGES[action],),
                                (f"{keys.rig_prefix(rig)}/**",)))
    return rules


def access_control(rig: str) -> dict:
    """The router's Zenoh ``access_control`` section for `rig`: deny, except what `grants` allows."""
    rules, subjects, policies = [], [], []
    for identity, grant in grants(rig).items():
        own = _rules(identity, grant, rig)
        rules += own
        subjects.append({"id": identity, "cert_common_names": [common_name(identity)]})
        policies.append({"id": identity, "rules": [rule["id"] for rule in own], "subjects": [identity]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


@dataclass(frozen=True)
class SecureDir:
    """A directory written by `camnet secure init`: the CA, an identity per node kind, the rig."""

    path: Path
    rig: str
    router_endpoints: tuple[str, ...] = field(default=())

    @property
    def ca_certificate(self) -> Path:
        return self.path / CA_CERTIFICATE

    @property
    def router_port(self) -> int:
        """The port `camnet secure init --port` gave the router: that of the endpoints nodes dial."""
        for endpoint in self.router_endpoints:
            port = endpoint.rsplit(":", 1)[-1]
            if port.isdigit():
                return int(port)
        return DEFAULT_PORT

    def certificate(self, identity: str) -> Path:
        return self.path / f"{identity}.pem"

    def private_key(self, identity: str) -> Path:
        return self.path / f"{identity}-key.pem"


def load_secure_dir(path: str | Path, identity: str) -> SecureDir:
    """The secure directory at `path`, checked to hold what `identity` needs; InputError if not."""
    path = Path(path)
    hint = "write one with `camnet secure init DIR --rig RIG`"
    manifest = path / MANIFEST
    try:
        doc = json.loads(manifest.read_text())
    except FileNotFoundError:
        raise InputError(f"--secure {path}: no {MANIFEST} there; {hint}") from None
    except (OSError, ValueError) as exc:
        raise InputError(f"--secure {path}: cannot read {MANIFEST} ({exc}); {hint}") from exc
    if not isinstance(doc, dict) or doc.get("format") != MANIFEST_FORMAT:
        raise InputError(f"--secure {path}: {MANIFEST} is not a {MANIFEST_FORMAT} file; {hint}")
    endpoints = doc.get("router_endpoints")
    if not isinstance(endpoints, list) or not all(isinstance(e, str) for e in endpoints):
        raise InputError(f"--secure {path}: {MANIFEST}: router_endpoints must be a list of endpoints")
    secure = SecureDir(path=path, rig=keys.validate_id(doc.get("rig"), what=f"{manifest}: rig"),
                       router_endpoints=tuple(endpoints))
    if identity not in IDENTITIES:
        raise InputError(f"--secure: no identity {identity!r}; expected one of {', '.join(IDENTITIES)}")
    for needed in (secure.ca_certificate, secure.certificate(identity), secure.private_key(identity)):
        if not needed.is_file():
            raise InputError(f"--secure {path}: {needed.name} missing: the {identity} needs it "
                             f"(copy it from the directory `camnet secure init` wrote)")
    return secure


def zenoh_settings(secure: SecureDir, identity: str, *, connect: tuple[str, ...] = (),
                   listen: tuple[str, ...] = ()) -> dict[str, object]:
    """Zenoh config keys and values for `identity` of `secure`'s rig (the router, or a node).

    Nodes are clients: they open no port, dial the router (`connect`, else the
    directory's endpoints) over TLS, wait for it if it is not up yet, and
    check that its certificate comes from the rig's CA and names the host they
    dialled. The router listens on `listen` (default: every interface, on the
    port the nodes dial, TLS only), demands a certificate from every node and enforces `access_control`.
    """
    tls = "transport/link/tls"
    settings: dict[str, object] = {
        "scouting/multicast/enabled": False,
        # Refuse any other protocol: a plain tcp link cannot be added by mistake.
        "transport/link/protocols": ["tls"],
        f"{tls}/root_ca_certificate": str(secure.ca_certificate.resolve()),
        f"{tls}/enable_mtls": True,
    }
    for endpoint in (*connect, *listen):
        if not endpoint.startswith("tls/"):
            raise InputError(f"--secure: endpoint {endpoint!r} is not TLS; give tls/HOST:PORT")
    if identity == ROUTER:
        settings.update({
            "mode": "router",
            "listen/endpoints": list(listen or (f"tls/[::]:{secure.router_port}",)),
            f"{tls}/listen_certificate": str(secure.certificate(identity).resolve()),
            f"{tls}/listen_private_key": str(secure.private_key(identity).resolve()),
            "access_control": access_control(secure.rig),
        })
        if connect:
            settings["connect/endpoints"] = list(connect)
        return settings
    if listen:
        raise InputError(f"--listen {listen[0]}: a node with --secure is a client of the router and "
                         "listens on nothing; drop --listen")
    endpoints = connect or secure.router_endpoints
    if not endpoints:
        raise InputError(f"--secure {secure.path}: no router endpoint; give --connect tls/ROUTER:PORT")
    settings.update({
        "mode": "client",
        "connect/endpoints": list(endpoints),
        # A client cannot open without its router: each try of opening the session gives up
        # after this long, and camnet.bus.session tries again, saying so.
        "connect/timeout_ms": CONNECT_TRY_MS,
        "connect/exit_on_failure": False,
        f"{tls}/connect_certificate": str(secure.certificate(identity).resolve()),
        f"{tls}/connect_private_key": str(secure.private_key(identity).resolve()),
    })
    return settings


def watch_identities(session) -> None:
    """Log who joins and leaves the router `session`, by identity, for as long as it is open.

    A peer refused during the TLS handshake (no certificate, or one from
    another CA) never gets a link: Zenoh logs those itself. One with a
    certificate of the rig's CA that names no identity gets a link on which
    the access control refuses everything; that is logged here.
    """
    import zenoh

    identities = {common_name(identity): identity for identity in IDENTITIES}

    def on_event(event) -> None:
        link = event.link
        name = link.auth_identifier
        if event.kind == zenoh.SampleKind.DELETE:
            log.info("%s (%s) left", identities.get(name, name), link.dst)
        elif name in identities:
            log.info("admitted the %s (%s) from %s", identities[name], name, link.dst)
        else:
            log.warning("%s joined with certificate %r, which names no camnet identity: the access control "
                        "refuses everything it sends and sends it nothing", link.dst, name)

    session.info.declare_link_events_listener(on_event, history=True)
