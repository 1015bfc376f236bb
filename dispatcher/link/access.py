"""Who may say what on the farm's Zenoh network: TLS identities and the access-control list.

Every process proves who it is with a certificate of the farm's own certificate authority
(mutual TLS: the listener checks the connector's certificate as well as the other way
round), and the process everyone connects to (the dispatcher, or ``agrifleet router``) lets
each identity publish only on its own keys:

- ``dispatcher``: everything under ``agrifleet/<farm>/``; the only one that may publish on
  a vehicle's ``…/mavlink/to``;
- ``<vehicle id>``: its own ``…/mavlink/from`` and ``…/alive``, and hears only its own keys;
- ``operator``: viewers and tools (status queries, the plan, watching); publishes nothing.

A session without a certificate of the farm's authority cannot connect at all; an
authenticated one that publishes on another's keys is dropped where it enters (the ACL's
ingress rules), so it reaches neither the dispatcher nor a vehicle.

A TLS folder (made by ``agrifleet certs``, :func:`make_farm_pki`) holds ``ca.pem``, and for
each identity ``<name>.pem`` (certificate, common name = the identity) and ``<name>.key``
(private key, mode 600). :func:`access_control` is the ACL block for a farm, the same
whether the dispatcher or a router applies it; ``certs`` writes it as well, with a complete
zenohd configuration, for those who run their own router. docs/security.md has the set-up.
"""

from __future__ import annotations

import datetime
import ipaddress
import json
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from dispatcher.config.errors import ConfigError
from dispatcher.link import wire
from dispatcher.link.keys import (
    PRIVATE_MODE,
    private_folder,
    refuse_unless_closed,
    refuse_unless_private,
    write_file,
)

DISPATCHER = "dispatcher"
ROUTER = "router"
OPERATOR = "operator"
SERVERS = (DISPATCHER, ROUTER)
"""The identities others connect to (TLS servers); every other is a client only."""
CA_FILE = "ca.pem"
ACL_FILE = "acl.json5"
ZENOHD_FILE = "zenohd.json5"
CERT_SUFFIX = ".pem"
KEY_SUFFIX = ".key"
DEFAULT_HOSTS = ("localhost", "127.0.0.1", "::1")
CA_DAYS = 3650
PUBLIC_MODE = 0o644  # certificates and the ACL: anyone may read them
LEAF_DAYS = 825  # the longest a public CA may sign for; renew with `agrifleet certs --replace`

ALL_MESSAGES = (
    "put",
    "delete",
    "declare_subscriber",
    "query",
    "reply",
    "declare_queryable",
    "liveliness_token",
    "liveliness_query",
    "declare_liveliness_subscriber",
)
WATCH_MESSAGES = (
    "query",
    "declare_subscriber",
    "liveliness_query",
    "declare_liveliness_subscriber",
)
INTEREST_MESSAGES = ("declare_subscriber", "declare_liveliness_subscriber")


class AccessError(ConfigError):
    """A TLS folder that is missing a file, or a private key open to others."""


@dataclass(frozen=True)
class TlsIdentity:
    """One identity's files in a TLS folder."""

    folder: Path
    name: str

    @property
    def ca(self) -> Path:
        return self.folder / CA_FILE

    @property
    def cert(self) -> Path:
        return self.folder / f"{self.name}{CERT_SUFFIX}"

    @property
    def key(self) -> Path:
        return self.folder / f"{self.name}{KEY_SUFFIX}"

    def check(self) -> TlsIdentity:
        """Self, once its three files are there and its key is its owner's only; else
        :class:`AccessError` naming the file."""
        for path in (self.ca, self.cert):
            if not path.is_file():
                raise AccessError(
                    f"{path}: missing; make the farm's certificates with "
                    f"`agrifleet certs SCENARIO --tls {self.folder}`"
                )
        check_private(self.key, f"the TLS key of {self.name!r}", f"--tls {self.folder}")
        _check_pem(self.ca, self.cert, self.key, f"agrifleet certs SCENARIO --tls {self.folder}")
        return self

    def settings(self) -> list[tuple[str, str]]:
        """The Zenoh configuration of mutual TLS with this identity (``insert_json5`` pairs),
        for listening and connecting alike."""
        tls = "transport/link/tls/"
        ca, cert, key = (json.dumps(str(p.resolve())) for p in (self.ca, self.cert, self.key))
        return [
            (tls + "root_ca_certificate", ca),
            (tls + "listen_certificate", cert),
            (tls + "listen_private_key", key),
            (tls + "connect_certificate", cert),
            (tls + "connect_private_key", key),
            (tls + "enable_mtls", "true"),
            (tls + "verify_name_on_connect", "true"),
        ]


def _check_pem(ca_path: Path, cert_path: Path, key_path: Path, make: str) -> None:
    """The three files read as what they should be: two certificates, the identity's
    issued by the CA and in date, and the private key of the identity's certificate.
    Zenoh said only "peer sent no certificates" or "KeyMismatch", naming no file, or a
    tractor's session never connected without a word (review)."""
    import datetime

    from cryptography import x509
    from cryptography.exceptions import InvalidSignature
    from cryptography.hazmat.primitives import serialization

    def certificate(path: Path) -> x509.Certificate:
        try:
            return x509.load_pem_x509_certificate(path.read_bytes())
        except (OSError, ValueError) as exc:
            raise AccessError(
                f"{path}: not a PEM certificate ({exc}); make it with `{make}`"
            ) from None

    ca, cert = certificate(ca_path), certificate(cert_path)
    try:
        key = serialization.load_pem_private_key(key_path.read_bytes(), password=None)
    except (OSError, ValueError, TypeError) as exc:
        raise AccessError(
            f"{key_path}: not a PEM private key without a password ({exc}); make it with `{make}`"
        ) from None
    raw = serialization.Encoding.DER, serialization.PublicFormat.SubjectPublicKeyInfo
    if key.public_key().public_bytes(*raw) != cert.public_key().public_bytes(*raw):
        raise AccessError(f"{key_path}: not the private key of the certificate {cert_path}")
    try:
        cert.verify_directly_issued_by(ca)
    except (ValueError, TypeError, InvalidSignature):
        raise AccessError(
            f"{cert_path}: not issued by the farm's CA {ca_path} (certificates of another "
            f"farm, or made again since?); make them with `{make}`"
        ) from None
    now = datetime.datetime.now(datetime.UTC)
    for path, c in ((ca_path, ca), (cert_path, cert)):
        if not c.not_valid_before_utc <= now <= c.not_valid_after_utc:
            raise AccessError(
                f"{path}: valid from {c.not_valid_before_utc:%Y-%m-%d} to "
                f"{c.not_valid_after_utc:%Y-%m-%d}, not now; make new ones with `{make}`"
            )


def check_private(path: Path, what: str, remedy: str) -> None:
    """A private file must exist, be readable by its owner only and belong to the user
    agrifleet runs as or root (as ssh wants of a private key); :class:`AccessError` names
    the file and the fix."""
    try:
        status = path.stat()
    except FileNotFoundError:
        raise AccessError(
            f"{path}: missing ({what}); make it with `agrifleet certs SCENARIO {remedy}`"
        ) from None
    refuse_unless_private(status, path, what, AccessError)
    refuse_unless_closed(path.parent, "the farm's certificates", AccessError)


# --- the access-control list --------------------------------------------------------


def _rule(rule_id: str, flow: str, messages: Sequence[str], keys: Sequence[str]) -> dict[str, Any]:
    return {
        "id": rule_id,
        "permission": "allow",
        "flows": [flow],
        "messages": list(messages),
        "key_exprs": list(keys),
    }


def access_control(farm: str, vehicle_ids: Iterable[str]) -> dict[str, Any]:
    """The ``access_control`` block of the process everyone connects to: deny by default;
    the dispatcher everything on the farm's keys; each vehicle its own keys only (it may
    publish on ``from``/``alive`` and subscribe to ``to``, and hears nothing of others);
    an operator may watch and query but not publish."""
    farm_keys = f"{wire.PREFIX}/{farm}/**"
    rules = [
        _rule("dispatcher-in", "ingress", ALL_MESSAGES, [farm_keys]),
        _rule("dispatcher-out", "egress", ALL_MESSAGES, [farm_keys]),
        _rule("operator-in", "ingress", WATCH_MESSAGES, [farm_keys]),
        _rule("operator-out", "egress", ALL_MESSAGES, [farm_keys]),
        # A peer publishes only where it knows of a subscriber: a vehicle must learn that
        # the dispatcher listens on ``vehicle/*/mavlink/from`` (who listens, never what).
        _rule("interest-out", "egress", INTEREST_MESSAGES, [farm_keys]),
    ]
    subjects = [
        {"id": DISPATCHER, "cert_common_names": [DISPATCHER]},
        {"id": OPERATOR, "cert_common_names": [OPERATOR]},
    ]
    policies = [
        {"id": DISPATCHER, "rules": ["dispatcher-in", "dispatcher-out"], "subjects": [DISPATCHER]},
        {"id": OPERATOR, "rules": ["operator-in", "operator-out"], "subjects": [OPERATOR]},
    ]
    for vid in vehicle_ids:
        own = f"{wire.PREFIX}/{farm}/vehicle/{vid}/**"
        ids = [f"{vid}-says", f"{vid}-alive", f"{vid}-listens", f"{vid}-hears"]
        rules += [
            _rule(ids[0], "ingress", ("put",), [wire.vehicle_from(farm, vid)]),
            _rule(ids[1], "ingress", ("liveliness_token",), [wire.vehicle_alive(farm, vid)]),
            _rule(ids[2], "ingress", ("declare_subscriber",), [wire.vehicle_to(farm, vid)]),
            _rule(ids[3], "egress", ALL_MESSAGES, [own]),
        ]
        subjects.append({"id": f"vehicle-{vid}", "cert_common_names": [vid]})
        subject = f"vehicle-{vid}"
        policies.append({"id": subject, "rules": [*ids, "interest-out"], "subjects": [subject]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def as_hub(options: wire.ZenohOptions, acl: dict[str, Any]) -> wire.ZenohOptions:
    """``options`` applying ``acl`` when others connect to this process over TLS (the
    dispatcher listening, or a router); unchanged otherwise. Listening as the session will,
    however set (a ``--zenoh-config`` file's endpoints too: they listened without the list,
    and a vehicle could put on another's keys)."""
    if options.tls is None or not options.listens():
        return options
    return replace(options, acl=acl)


def zenohd_config(identity: TlsIdentity, acl: dict[str, Any], listen: Sequence[str]) -> dict:
    """A complete configuration for a stock ``zenohd`` router as the farm's hub."""
    conf: dict[str, Any] = {
        "mode": "router",
        "listen": {"endpoints": list(listen)},
        "scouting": {"multicast": {"enabled": False}},
        "access_control": acl,
    }
    for path, value in identity.settings():
        node = conf
        *parents, leaf = path.split("/")
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = json.loads(value)
    return conf


# --- the farm's certificate authority ----------------------------------------------


def make_farm_pki(
    folder: str | os.PathLike[str],
    farm: str,
    vehicle_ids: Sequence[str],
    hosts: Sequence[str] = DEFAULT_HOSTS,
    replace: bool = False,
    now: datetime.datetime | None = None,
) -> list[Path]:
    """A certificate authority for ``farm`` and a certificate for the dispatcher, a router,
    an operator and each vehicle, in ``folder`` (mode 700; private keys mode 600), with the
    farm's ACL and a zenohd configuration; the paths written. Existing files are kept
    unless ``replace``. ``hosts`` are the names and addresses the listeners (dispatcher,
    router) are reached at: a connector checks the listener's certificate against them."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    reserved = sorted({DISPATCHER, ROUTER, OPERATOR, "ca"} & set(vehicle_ids))
    if reserved:
        raise AccessError(
            f"vehicle id {reserved[0]!r} is the name of another identity on the farm's network; "
            "rename the vehicle"
        )
    out = Path(folder)
    private_folder(out, "the farm's certificates", AccessError)
    now = now or datetime.datetime.now(datetime.UTC)
    written: list[Path] = []

    def write(path: Path, data: bytes, private: bool) -> None:
        write_file(path, data, PRIVATE_MODE if private else PUBLIC_MODE)
        written.append(path)

    def key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
        return key.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.NoEncryption(),
        )

    ca_cert_path, ca_key_path = out / CA_FILE, out / f"ca{KEY_SUFFIX}"
    if ca_cert_path.exists() and ca_key_path.exists() and not replace:
        check_private(ca_key_path, "the farm's CA key", f"--tls {out}")
        ca_key = serialization.load_pem_private_key(ca_key_path.read_bytes(), password=None)
        ca_cert = x509.load_pem_x509_certificate(ca_cert_path.read_bytes())
        if not isinstance(ca_key, ec.EllipticCurvePrivateKey):
            raise AccessError(f"{ca_key_path}: not an elliptic-curve key")
    else:
        ca_key = ec.generate_private_key(ec.SECP256R1())
        ca_name = x509.Name(
            [
                x509.NameAttribute(NameOID.ORGANIZATION_NAME, f"agrifleet farm {farm}"),
                x509.NameAttribute(NameOID.COMMON_NAME, f"{farm} farm CA"),
            ]
        )
        ca_cert = (
            x509.CertificateBuilder()
            .subject_name(ca_name)
            .issuer_name(ca_name)
            .public_key(ca_key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=CA_DAYS))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(
                x509.KeyUsage(
                    digital_signature=True,
                    content_commitment=False,
                    key_encipherment=False,
                    data_encipherment=False,
                    key_agreement=False,
                    key_cert_sign=True,
                    crl_sign=True,
                    encipher_only=False,
                    decipher_only=False,
                ),
                critical=True,
            )
            .add_extension(
                x509.SubjectKeyIdentifier.from_public_key(ca_key.public_key()), critical=False
            )
            .sign(ca_key, hashes.SHA256())
        )
        write(ca_key_path, key_pem(ca_key), private=True)
        write(ca_cert_path, ca_cert.public_bytes(serialization.Encoding.PEM), private=False)

    alt_names: list[x509.GeneralName] = []
    for host in hosts:
        try:
            alt_names.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            alt_names.append(x509.DNSName(host))

    for name in [DISPATCHER, ROUTER, OPERATOR, *vehicle_ids]:
        identity = TlsIdentity(out, name)
        if identity.cert.exists() and identity.key.exists() and not replace:
            continue
        key = ec.generate_private_key(ec.SECP256R1())
        # Only the dispatcher and a router are listened to: a tractor's or the operator's
        # certificate is a client's alone, without the gateway's names (with them, a process
        # holding a tractor's files could pose as the dispatcher to the other tractors:
        # review).
        server = name in SERVERS
        names = alt_names if server else [x509.DNSName(name)]
        usage = [ExtendedKeyUsageOID.SERVER_AUTH] if server else []
        cert = (
            x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)]))
            .issuer_name(ca_cert.subject)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=LEAF_DAYS))
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.SubjectAlternativeName(names), critical=False)
            .add_extension(
                x509.ExtendedKeyUsage([*usage, ExtendedKeyUsageOID.CLIENT_AUTH]),
                critical=False,
            )
            .add_extension(
                x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()),
                critical=False,
            )
            .sign(ca_key, hashes.SHA256())
        )
        write(identity.key, key_pem(key), private=True)
        write(identity.cert, cert.public_bytes(serialization.Encoding.PEM), private=False)

    acl = access_control(farm, vehicle_ids)
    write(out / ACL_FILE, (json.dumps(acl, indent=2) + "\n").encode(), private=False)
    zenohd = zenohd_config(TlsIdentity(out, ROUTER), acl, ["tls/0.0.0.0:7447"])
    write(out / ZENOHD_FILE, (json.dumps(zenohd, indent=2) + "\n").encode(), private=False)
    return written


def read_acl(folder: str | os.PathLike[str]) -> dict[str, Any]:
    """The ACL ``agrifleet certs`` wrote into a TLS folder (for a router, which knows no
    scenario)."""
    path = Path(folder) / ACL_FILE
    try:
        acl = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise AccessError(
            f"{path}: missing; make it with `agrifleet certs SCENARIO --tls {folder}`"
        ) from None
    except (OSError, ValueError) as exc:
        raise AccessError(f"{path}: not an access-control list: {exc}") from exc
    if not isinstance(acl, dict) or acl.get("enabled") is not True:
        raise AccessError(f"{path}: not an enabled access-control list")
    return acl
