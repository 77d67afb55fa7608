"""Writing a rig's secrets: its CA, and a certificate and key for the router and each node kind.

The openssl command line makes them: camnet depends on no cryptography
package, and openssl is on every host that runs Zenoh's TLS anyway (the
docker deployment's script uses it too). Keys are EC P-256. The router's
certificate names the hosts nodes dial it by (Zenoh checks the name); a
node's certificate names its identity in its common name, which the
router's access control (camnet.bus.security) goes by.

Everything is written into a scratch directory beside the target and
renamed into place at the end, so an error halfway leaves nothing behind.
The directory is private (0700), private keys are 0600.
"""

from __future__ import annotations

import ipaddress
import json
import os
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from pathlib import Path

from camnet.bus.security import (
    CA_CERTIFICATE,
    CA_PRIVATE_KEY,
    DEFAULT_PORT,
    IDENTITIES,
    MANIFEST,
    MANIFEST_FORMAT,
    ROUTER,
    SecureDir,
    common_name,
)
from camnet.errors import CamnetError, InputError
from camnet.ids import validate_id

CA_DAYS = 3650
CERTIFICATE_DAYS = 825
PRIVATE_DIRECTORY_MODE = 0o700
PRIVATE_FILE_MODE = 0o600
PUBLIC_FILE_MODE = 0o644
_KEY = ("-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes")


def subject_alt_names(hosts: Sequence[str]) -> str:
    """The router certificate's subjectAltName: `hosts` and loopback, as IP or DNS names."""
    names = []
    for host in (*hosts, "localhost", "127.0.0.1", "::1"):
        if not host or any(c in host for c in " ,/:[]") and not _is_ip(host):
            raise InputError(f"--router-host {host!r}: expected a host name or an IP address")
        name = f"IP:{host}" if _is_ip(host) else f"DNS:{host}"
        if name not in names:
            names.append(name)
    return ",".join(names)


def _is_ip(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
        return True
    except ValueError:
        return False


def endpoint(host: str, port: int) -> str:
    return f"tls/[{host}]:{port}" if ":" in host else f"tls/{host}:{port}"


def _openssl(scratch: Path, *args: str) -> None:
    done = subprocess.run(["openssl", *args], cwd=scratch, capture_output=True, text=True, timeout=60)
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["no message"])[-1]
        raise CamnetError(f"openssl {args[0]} failed: {last}")


def _sign(scratch: Path, identity: str, extensions: Sequence[str]) -> None:
    """`identity`.pem and `identity`-key.pem, signed by the CA in `scratch`."""
    _openssl(scratch, "req", *_KEY, "-subj", f"/CN={common_name(identity)}",
             "-keyout", f"{identity}-key.pem", "-out", f"{identity}.csr")
    (scratch / f"{identity}.ext").write_text("\n".join(extensions) + "\n")
    _openssl(scratch, "x509", "-req", "-in", f"{identity}.csr", "-CA", CA_CERTIFICATE, "-CAkey", CA_PRIVATE_KEY,
             "-CAcreateserial", "-days", str(CERTIFICATE_DAYS), "-extfile", f"{identity}.ext",
             "-out", f"{identity}.pem")
    for leftover in (f"{identity}.csr", f"{identity}.ext"):
        (scratch / leftover).unlink()


def write_rig_secrets(directory: str | Path, *, rig: str, router_hosts: Sequence[str],
                      port: int = DEFAULT_PORT, force: bool = False) -> SecureDir:
    """Write the CA, the router's and every node kind's certificate and key, and the manifest."""
    directory = Path(directory)
    rig = validate_id(rig, what="--rig")
    if not router_hosts:
        raise InputError("--router-host: give the name or address the nodes dial the router by")
    if not 0 < port < 65536:
        raise InputError(f"--port {port}: expected 1-65535")
    sans = subject_alt_names(router_hosts)
    if directory.exists() and not force:
        raise InputError(f"{directory}: exists; give --force to replace every secret in it "
                         "(then restart the router and every node)")
    if not directory.parent.is_dir():
        raise InputError(f"{directory}: directory {directory.parent} does not exist")
    if shutil.which("openssl") is None:
        raise CamnetError("openssl not found: install it (Debian: apt-get install openssl)")
    # mkdtemp makes the scratch directory private (0700) before any key is in it.
    scratch = Path(tempfile.mkdtemp(dir=directory.parent, prefix=f".{directory.name}.", suffix=".tmp"))
    try:
        # A name of its own: a certificate from an earlier CA of the rig is then named as such when refused.
        ca_name = f"camnet rig {rig} CA {os.urandom(4).hex()}"
        _openssl(scratch, "req", "-x509", *_KEY, "-days", str(CA_DAYS), "-subj", f"/CN={ca_name}",
                 "-addext", "basicConstraints=critical,CA:TRUE", "-addext", "keyUsage=critical,keyCertSign,cRLSign",
                 "-keyout", CA_PRIVATE_KEY, "-out", CA_CERTIFICATE)
        leaf = ("basicConstraints=critical,CA:FALSE", "keyUsage=critical,digitalSignature")
        for identity in IDENTITIES:
            usage = ("extendedKeyUsage=serverAuth", f"subjectAltName={sans}") if identity == ROUTER else \
                ("extendedKeyUsage=clientAuth",)
            _sign(scratch, identity, (*leaf, *usage))
        (scratch / f"{Path(CA_CERTIFICATE).stem}.srl").unlink(missing_ok=True)
        endpoints = [endpoint(host, port) for host in router_hosts]
        (scratch / MANIFEST).write_text(json.dumps(
            {"format": MANIFEST_FORMAT, "rig": rig, "router_endpoints": endpoints}, indent=1) + "\n")
        for path in scratch.iterdir():
            path.chmod(PRIVATE_FILE_MODE if path.name.endswith("-key.pem") else PUBLIC_FILE_MODE)
        _move_into_place(scratch, directory)
    except BaseException:
        shutil.rmtree(scratch, ignore_errors=True)
        raise
    return SecureDir(path=directory, rig=rig, router_endpoints=tuple(endpoints))


def _move_into_place(scratch: Path, directory: Path) -> None:
    """Rename `scratch` to `directory`; an old `directory` goes only once the new one is there."""
    old = None
    if directory.exists():
        old = directory.with_name(f".{directory.name}.old-{os.getpid()}")
        directory.rename(old)
    scratch.rename(directory)
    if old is not None:
        shutil.rmtree(old)
