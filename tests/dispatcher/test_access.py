"""The farm's certificates, access-control list and TLS options (dispatcher/link/access.py)."""

from __future__ import annotations

import argparse
import json
import stat
from pathlib import Path

import pytest
import zenoh
from cryptography import x509
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from dispatcher.cli.main import main
from dispatcher.config.errors import ConfigError
from dispatcher.config.scenario import load_scenario
from dispatcher.link import wire
from dispatcher.link.access import (
    ACL_FILE,
    DISPATCHER,
    ROUTER,
    AccessError,
    TlsIdentity,
    access_control,
    as_hub,
    make_farm_pki,
    read_acl,
    zenohd_config,
)

CONFIG = Path(__file__).resolve().parents[2] / "config"
EXAMPLE = CONFIG / "zenoh" / "changji-router.json5"


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("pki") / "tls"
    make_farm_pki(folder, "f", ["v1", "v2"], hosts=("localhost", "10.0.0.2"))
    return folder


def test_each_identity_has_a_certificate_of_the_farms_ca_and_a_private_key(pki: Path) -> None:
    ca = x509.load_pem_x509_certificate((pki / "ca.pem").read_bytes())
    for name in ("dispatcher", "router", "operator", "v1", "v2"):
        cert = x509.load_pem_x509_certificate((pki / f"{name}.pem").read_bytes())
        assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == name
        assert cert.issuer == ca.subject
        cert.verify_directly_issued_by(ca)
        names = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        usage = cert.extensions.get_extension_for_class(x509.ExtendedKeyUsage).value
        if name in ("dispatcher", "router"):  # listened to: the gateway's names, a server's
            assert "localhost" in names.get_values_for_type(x509.DNSName)
            assert [str(a) for a in names.get_values_for_type(x509.IPAddress)] == ["10.0.0.2"]
            assert ExtendedKeyUsageOID.SERVER_AUTH in usage
        else:  # a client only: it cannot pose as the dispatcher (review)
            assert names.get_values_for_type(x509.DNSName) == [name]
            assert ExtendedKeyUsageOID.SERVER_AUTH not in usage
        assert ExtendedKeyUsageOID.CLIENT_AUTH in usage
        assert stat.S_IMODE((pki / f"{name}.key").stat().st_mode) == 0o600
    assert stat.S_IMODE(pki.stat().st_mode) == 0o700
    assert stat.S_IMODE((pki / "ca.key").stat().st_mode) == 0o600


def test_existing_certificates_are_kept_and_a_new_vehicle_gets_one(pki: Path) -> None:
    before = (pki / "v1.pem").read_bytes()
    written = make_farm_pki(pki, "f", ["v1", "v2", "v3"])
    assert pki / "v3.pem" in written and pki / "v1.pem" not in written
    assert (pki / "v1.pem").read_bytes() == before
    ca = x509.load_pem_x509_certificate((pki / "ca.pem").read_bytes())
    x509.load_pem_x509_certificate((pki / "v3.pem").read_bytes()).verify_directly_issued_by(ca)


def test_a_key_open_to_others_or_missing_is_refused_naming_the_file(pki: Path) -> None:
    identity = TlsIdentity(pki, "v2").check()
    identity.key.chmod(0o640)
    try:
        with pytest.raises(AccessError, match=r"v2\.key.*chmod 600"):
            identity.check()
    finally:
        identity.key.chmod(0o600)
    with pytest.raises(AccessError, match=r"nobody\.pem: missing.*agrifleet certs"):
        TlsIdentity(pki, "nobody").check()


def test_a_bad_certificate_or_key_is_refused_naming_the_file(tmp_path: Path) -> None:
    """Garbage for a certificate, another identity's key, another farm's CA: Zenoh said
    "peer sent no certificates" or "KeyMismatch" naming no file, and a tractor's session
    never connected without a word (review)."""
    import shutil

    folder = tmp_path / "tls"
    make_farm_pki(folder, "f", ["v1", "v2"])
    other = tmp_path / "other"
    make_farm_pki(other, "g", ["v1"])
    v1 = TlsIdentity(folder, "v1")
    v1.check()
    good_cert, good_key = v1.cert.read_bytes(), v1.key.read_bytes()
    v1.cert.write_text("not a certificate")
    with pytest.raises(AccessError, match=r"v1\.pem: not a PEM certificate"):
        v1.check()
    v1.cert.write_bytes(good_cert)
    v1.key.write_bytes((folder / "v2.key").read_bytes())
    with pytest.raises(AccessError, match=r"v1\.key: not the private key of the certificate"):
        v1.check()
    v1.key.write_bytes(good_key)
    shutil.copy(other / "ca.pem", folder / "ca.pem")
    with pytest.raises(AccessError, match=r"v1\.pem: not issued by the farm's CA"):
        v1.check()


def test_certificates_are_not_made_in_a_folder_others_may_write_in(tmp_path: Path) -> None:
    folder = tmp_path / "tls"
    folder.mkdir()
    folder.chmod(0o777)
    with pytest.raises(AccessError, match=r"tls: the folder of the farm's certificates may be"):
        make_farm_pki(folder, "f", ["v1"])
    assert not list(folder.iterdir())


def test_a_vehicle_named_as_another_identity_is_refused(tmp_path: Path) -> None:
    with pytest.raises(AccessError, match="'dispatcher'"):
        make_farm_pki(tmp_path / "tls", "f", ["v1", DISPATCHER])


def test_the_acl_lets_each_vehicle_publish_on_its_own_keys_only() -> None:
    acl = access_control("f", ["v1", "v2"])
    assert acl["enabled"] is True and acl["default_permission"] == "deny"
    rules = {r["id"]: r for r in acl["rules"]}
    policy = {p["id"]: p for p in acl["policies"]}["vehicle-v1"]
    ingress = [rules[r] for r in policy["rules"] if rules[r]["flows"] == ["ingress"]]
    keys = {k for r in ingress for k in r["key_exprs"]}
    assert keys == {
        wire.vehicle_from("f", "v1"),
        wire.vehicle_alive("f", "v1"),
        wire.vehicle_to("f", "v1"),
    }
    [to_rule] = [r for r in ingress if r["key_exprs"] == [wire.vehicle_to("f", "v1")]]
    assert to_rule["messages"] == ["declare_subscriber"]  # it listens there, never says
    operator = {p["id"]: p for p in acl["policies"]}["operator"]
    operator_in = [rules[r] for r in operator["rules"] if rules[r]["flows"] == ["ingress"]]
    assert all("put" not in r["messages"] for r in operator_in)


def test_certs_writes_the_acl_a_router_reads(pki: Path) -> None:
    assert read_acl(pki) == json.loads((pki / ACL_FILE).read_text())
    assert read_acl(pki) == access_control("f", ["v1", "v2", "v3"])


def test_the_shipped_router_example_is_what_certs_writes_for_the_demo_farm() -> None:
    scenario = load_scenario(CONFIG / "changji.toml")
    ids = [v.id for v in scenario.vehicles]
    conf = zenohd_config(
        TlsIdentity(Path("/etc/agrifleet/tls"), ROUTER),
        access_control(scenario.farm_id, ids),
        ["tls/0.0.0.0:7447"],
    )
    lines = [ln for ln in EXAMPLE.read_text().splitlines() if not ln.startswith("//")]
    assert json.loads("\n".join(lines)) == conf
    loaded = zenoh.Config.from_file(str(EXAMPLE))  # zenohd reads it: comments and all
    assert json.loads(loaded.get_json("access_control/default_permission")) == "deny"


def args(**kw: object) -> argparse.Namespace:
    base = dict(mode="peer", listen=None, connect=None, zenoh_config=None, cfg=None, tls=None)
    return argparse.Namespace(**{**base, **kw})


def test_a_plain_listener_beyond_loopback_is_refused_unless_asked_for() -> None:
    with pytest.raises(ConfigError, match="without TLS.*--insecure-listen"):
        wire.zenoh_options(args(listen=["tcp/0.0.0.0:7447"]), True)
    wire.zenoh_options(args(listen=["tcp/0.0.0.0:7447"], insecure_listen=True), True)
    wire.zenoh_options(args(listen=["tcp/127.0.0.1:7447"]), True)
    wire.zenoh_options(args(listen=["tcp/[::1]:7447"]), True)


def test_with_tls_the_default_endpoint_is_tls_and_a_plain_one_is_refused(pki: Path) -> None:
    options = wire.zenoh_options(args(tls=str(pki)), False, identity="v1")
    assert options.connect == (wire.DEFAULT_TLS_ENDPOINT,) and options.tls is not None
    assert options.tls.name == "v1"
    assert options.as_identity("v2").tls.name == "v2"  # type: ignore[union-attr]
    conf = options.config()
    assert json.loads(conf.get_json("transport/link/tls/enable_mtls")) is True
    plain = wire.zenoh_options(args(tls=str(pki), connect=["tcp/127.0.0.1:7447"]), False)
    with pytest.raises(ConfigError, match="tcp/127.0.0.1:7447 would let anyone in"):
        plain.config()


@pytest.mark.parametrize("how", ["--listen", "--zenoh-config", "--cfg"])
def test_the_dispatcher_listening_over_tls_applies_the_acl_however_told(
    pki: Path, tmp_path: Path, how: str
) -> None:
    """serve with --tls and its listener in a --zenoh-config file (or --cfg) listened
    without the access-control list: a vehicle's certificate could put on another's
    keys."""
    endpoint = "tls/127.0.0.1:17447"
    file = tmp_path / "zenoh.json5"
    file.write_text(json.dumps({"listen": {"endpoints": [endpoint]}}))
    told = {
        "--listen": {"listen": [endpoint]},
        "--zenoh-config": {"zenoh_config": str(file)},
        "--cfg": {"cfg": [f'listen/endpoints:["{endpoint}"]']},
    }[how]
    options = as_hub(
        wire.zenoh_options(args(tls=str(pki), **told), True), access_control("f", ["v1"])
    )
    conf = options.config()
    assert json.loads(conf.get_json("listen/endpoints")) == [endpoint]
    assert json.loads(conf.get_json("access_control/enabled")) is True


def test_a_peer_listens_on_loopback_only_and_with_tls_nowhere_unless_told(pki: Path) -> None:
    conf = wire.ZenohOptions(connect=("tcp/127.0.0.1:7447",)).config()
    assert json.loads(conf.get_json("listen/endpoints")) == [wire.LOOPBACK_PEER_ENDPOINT]
    tls = TlsIdentity(pki, "v1")
    conf = wire.ZenohOptions(connect=("tls/127.0.0.1:7447",), tls=tls).config()
    assert json.loads(conf.get_json("listen/endpoints")) == []


def test_agrifleet_certs_writes_the_folder(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    folder = tmp_path / "tls"
    assert main(["certs", str(CONFIG / "changji.toml"), "--tls", str(folder)]) == 0
    out = capsys.readouterr().out
    assert "keep ca.key off the farm network" in out
    assert (folder / "t1.pem").is_file() and (folder / "zenohd.json5").is_file()


def test_a_tractors_certificate_cannot_pose_as_the_dispatcher(tmp_path: Path) -> None:
    """A process holding only a tractor's certificate and key listened as the dispatcher and
    the other tractors connected to it (every certificate was a server's, with the
    gateway's names: review). Only the dispatcher's and a router's are servers now."""
    import socket

    folder = tmp_path / "tls"
    make_farm_pki(folder, "f", ["v1", "v2"], hosts=("localhost", "127.0.0.1"))

    def v2_connects_to(listener: str) -> bool:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            endpoint = f"tls/127.0.0.1:{s.getsockname()[1]}"
        tls = TlsIdentity(folder, listener)
        with zenoh.open(wire.ZenohOptions(listen=(endpoint,), tls=tls).config()):
            conf = wire.ZenohOptions(
                mode="client", connect=(endpoint,), tls=TlsIdentity(folder, "v2")
            ).config()
            conf.insert_json5("connect/timeout_ms", "2000")
            try:
                zenoh.open(conf).close()
            except zenoh.ZError:
                return False
            return True

    assert v2_connects_to(DISPATCHER)
    assert not v2_connects_to("v1")


def test_a_session_connected_to_nothing_says_so(monkeypatch, caplog) -> None:
    """Zenoh in peer mode keeps trying to connect without a word: a sim or bridge with a TLS
    folder of another farm, or an address the dispatcher's certificate does not name, ran
    on, reaching nothing, and said nothing."""
    from helpers.processes import free_port, wait_for

    monkeypatch.setattr(wire, "ALONE_WARN_S", 0.2)
    port = free_port()
    lonely = wire.ZenohOptions(connect=(f"tcp/127.0.0.1:{port}",))
    with caplog.at_level("WARNING", logger="dispatcher.link.wire"):
        session = lonely.open()
        try:
            wait_for("the warning", lambda: "connected to nothing" in caplog.text, 10.0)
        finally:
            session.close()
    assert f"connected to nothing at tcp/127.0.0.1:{port} after 0.2 s" in caplog.text
    caplog.clear()
    hub = wire.ZenohOptions(listen=(f"tcp/127.0.0.1:{port}",)).open()
    joined = lonely.open()
    try:
        wait_for("the peer", lambda: bool(list(joined.info.peers_zid())), 10.0)
        with caplog.at_level("WARNING", logger="dispatcher.link.wire"):
            lonely._say_if_alone(joined)
        assert "connected to nothing" not in caplog.text
    finally:
        joined.close()
        hub.close()
