"""MAVLink 2 signing: keys, the codec's checks, what the bridge passes on."""

from __future__ import annotations

import os
import re
import stat
import time
from pathlib import Path

import pytest

from dispatcher.cli.main import main
from dispatcher.config.scenario import load_scenario
from dispatcher.link import mavlink as mc
from dispatcher.link.keys import SigningKeyError, key_path, read_key, read_keys, write_keys

DATA = Path(__file__).resolve().parents[1] / "data"


def heartbeat() -> mc.MAVLinkMessage:
    return mc.peer_heartbeat(mc.MAV_TYPE_GROUND_ROVER)


def test_a_signed_frame_is_taken_and_unsigned_wrong_or_replayed_ones_are_dropped() -> None:
    key = os.urandom(32)
    dispatcher = mc.Codec(255, 190, key=key)
    vehicle = mc.Codec(11, 1, key=key)
    frame = dispatcher.encode(heartbeat())
    assert vehicle.decode_one(frame) is not None
    # The same frame again (a radio's copy, or a replay): dropped, counted as a copy, not
    # as a frame that failed the key (the warnings and review said so of a lossy radio's).
    assert vehicle.decode_one(frame) is None
    assert vehicle.decode_one(mc.Codec(255, 190).encode(heartbeat())) is None  # unsigned
    assert vehicle.decode_one(mc.Codec(255, 190, key=os.urandom(32)).encode(heartbeat())) is None
    assert vehicle.signing_stats == mc.SigningStats(good=1, bad=1, unsigned=1, duplicate=1)
    assert vehicle.signing_stats.dropped == 2
    assert vehicle.decode_one(dispatcher.encode(heartbeat())) is not None  # and on it goes


def test_a_forged_frame_from_the_future_does_not_lock_out_the_genuine_sender() -> None:
    """pymavlink's own check believes a frame's timestamp before its signature: one forged
    frame stamped far ahead would make every genuine frame after it look like a replay."""
    key = os.urandom(32)
    dispatcher, vehicle = mc.Codec(255, 190, key=key), mc.Codec(11, 1, key=key)
    assert vehicle.decode_one(dispatcher.encode(heartbeat())) is not None
    forger = mc.Codec(255, 190, key=os.urandom(32), timestamp=mc.signing_timestamp() + 10**12)
    assert vehicle.decode_one(forger.encode(heartbeat())) is None
    assert vehicle.decode_one(dispatcher.encode(heartbeat())) is not None


def test_timestamps_never_go_back_across_a_restart() -> None:
    key = os.urandom(32)
    first = mc.Codec(255, 190, key=key)
    for _ in range(3):
        first.encode(heartbeat())
    later = first.timestamp + 10**9  # kept ahead, as the store does
    again = mc.Codec(255, 190, key=key, timestamp=later)
    assert again.timestamp >= later > first.timestamp
    vehicle = mc.Codec(11, 1, key=key)
    assert vehicle.decode_one(again.encode(heartbeat())) is not None
    assert vehicle.decode_one(first.encode(heartbeat())) is None  # the old one: a replay


def test_an_unsigned_autopilot_frame_is_passed_on_signed_as_it_was() -> None:
    key = os.urandom(32)
    autopilot = mc.Codec(11, 1)
    sent = autopilot.decode_one(autopilot.encode(heartbeat()))
    assert sent is not None
    frame = mc.mavlink2_frame(sent, mc.Codec(11, 1, key=key))
    got = mc.Codec(255, 190, key=key).decode_one(frame)
    assert got is not None
    assert (got.get_srcSystem(), got.get_srcComponent(), got.get_seq()) == (11, 1, 0)
    signed = mc.Codec(11, 1, key=key).encode(heartbeat())
    signed_msg = mc.Codec(255, 190).decode_one(signed)
    assert signed_msg is not None
    assert mc.mavlink2_frame(signed_msg, mc.Codec(11, 1, key=key)) == signed  # as it came


def test_setup_signing_carries_the_key_to_the_autopilot() -> None:
    key = os.urandom(32)
    codec = mc.Codec(11, 191)
    msg = codec.decode_one(codec.encode(mc.setup_signing(11, key, 1234)))
    assert msg is not None and msg.get_type() == "SETUP_SIGNING"
    assert bytes(msg.secret_key) == key and msg.initial_timestamp == 1234


def test_keys_are_made_private_and_kept(tmp_path: Path) -> None:
    folder = tmp_path / "keys"
    written = write_keys(folder, ["t1", "t2"])
    assert written == [key_path(folder, "t1"), key_path(folder, "t2")]
    assert stat.S_IMODE(folder.stat().st_mode) == 0o700
    for path in written:
        assert stat.S_IMODE(path.stat().st_mode) == 0o600
    first = read_key(folder, "t1")
    assert len(first) == 32 and first != read_key(folder, "t2")
    assert write_keys(folder, ["t1", "t3"]) == [key_path(folder, "t3")]  # t1 kept
    assert read_key(folder, "t1") == first


def test_keys_go_into_no_file_planted_in_their_folder_and_an_open_folder_is_refused(
    tmp_path: Path,
) -> None:
    """The key was written through a fixed temporary name, following a symlink planted
    there into the planter's file, and an existing folder that others could write in was
    taken as it was."""
    folder = tmp_path / "keys"
    folder.mkdir(mode=0o700)
    theirs = tmp_path / "theirs"
    theirs.write_text("")
    (folder / "t1.key.tmp").symlink_to(theirs)
    write_keys(folder, ["t1"])
    assert theirs.read_text() == "" and not key_path(folder, "t1").is_symlink()
    assert read_key(folder, "t1") and sorted(p.name for p in folder.iterdir()) == [
        "t1.key",
        "t1.key.tmp",
    ]
    folder.chmod(0o777)
    with pytest.raises(SigningKeyError, match=r"keys: the folder of the signing keys may be "):
        write_keys(folder, ["t2"])
    folder.chmod(0o700)
    key_path(folder, "t2").mkdir(mode=0o700)  # not a file
    with pytest.raises(SigningKeyError, match=r"t2\.key: not a key file but a folder"):
        read_key(folder, "t2")


@pytest.mark.parametrize(
    ("mode", "text", "message"),
    [
        (0o644, None, "open to group or others (mode 644); make it the owner's only: chmod 600"),
        (0o600, "not hex at all", "not a signing key (64 hexadecimal digits expected)"),
        (0o600, "ab" * 16, "a signing key is 64 hexadecimal digits, found 32"),
        # Two keys pasted into one file were "found 129" (the newline counted): review
        (
            0o600,
            "ab" * 32 + "\n" + "cd" * 32 + "\n",
            "digits, found 128 on 2 lines (one key a file)",
        ),
        # All zeros turns signing off on ArduPilot, and anyone can sign with it (review).
        (0o600, "00" * 32, "not a secret key (one byte, 00, 32 times)"),
    ],
)
def test_a_bad_key_file_is_refused_naming_it(
    tmp_path: Path, mode: int, text: str | None, message: str
) -> None:
    write_keys(tmp_path, ["t1"])
    path = key_path(tmp_path, "t1")
    if text is not None:
        path.write_text(text)
    path.chmod(mode)
    with pytest.raises(SigningKeyError, match=re.escape(message)) as err:
        read_key(tmp_path, "t1")
    assert str(path) in str(err.value)


def test_a_pipe_in_place_of_a_key_file_is_refused_not_waited_on(tmp_path: Path) -> None:
    """A named pipe of mode 600 passed every check and `serve` waited on it for good (an
    outside review)."""
    (tmp_path / "keys").mkdir(mode=0o700)
    os.mkfifo(key_path(tmp_path / "keys", "t1"), 0o600)
    with pytest.raises(SigningKeyError, match=r"t1\.key: not a key file but a pipe"):
        read_key(tmp_path / "keys", "t1")


def test_a_key_file_of_another_user_is_refused_naming_both(tmp_path: Path, monkeypatch) -> None:
    """A key another user owns (mode 600 or not) is one that user can replace with theirs:
    refused, as ssh refuses such a private key; root's keys are taken."""
    write_keys(tmp_path, ["t1"])
    path = key_path(tmp_path, "t1")
    root = os.geteuid() == 0
    if root:
        os.chown(path, 4243, -1)  # the file another user's
    monkeypatch.setattr("dispatcher.link.keys.os.geteuid", lambda: 4242)
    with pytest.raises(SigningKeyError) as err:
        read_key(tmp_path, "t1")
    assert str(err.value).startswith(f"{path}: the signing key of 't1' belongs to ")
    assert "who could replace it, not to 4242 who runs agrifleet (or root): chown 4242" in str(
        err.value
    )
    if root:
        os.chown(path, 0, -1)
        assert read_key(tmp_path, "t1")  # root's


def test_keys_in_a_folder_others_may_write_are_refused_on_reading(
    tmp_path: Path, monkeypatch
) -> None:
    """Whoever may write in the keys' folder can rename a key of theirs over one there: the
    folder was checked when keys were made, not when read (review)."""
    folder = tmp_path / "keys"
    write_keys(folder, ["t1"])
    folder.chmod(0o770)
    with pytest.raises(SigningKeyError, match=r"keys: the folder of the signing keys may be "):
        read_key(folder, "t1")
    folder.chmod(0o700)
    assert read_key(folder, "t1")
    if os.geteuid() == 0:
        os.chown(folder, 4243, -1)  # the folder another user's
    monkeypatch.setattr("dispatcher.link.keys.os.geteuid", lambda: 4242)
    with pytest.raises(SigningKeyError, match=r"keys: the folder of the signing keys belongs to"):
        read_key(folder, "t1")


def test_two_vehicles_with_one_key_and_unsigned_with_keys_are_refused(
    tmp_path: Path, capsys
) -> None:
    """One key copied to two vehicles (either's leak commands both), and --unsigned beside
    --keys (it ran unsigned without a word): refused, naming the files or the options."""
    write_keys(tmp_path, ["t1", "t2"])
    key_path(tmp_path, "t2").write_text(key_path(tmp_path, "t1").read_text())
    with pytest.raises(SigningKeyError, match=r"t2\.key: the same key as .*t1\.key"):
        read_keys(tmp_path, ["t1", "t2"])
    code = main(["serve", str(DATA / "tiny.toml"), "--unsigned", "--keys", str(tmp_path)])
    assert code == 2 and "--unsigned and --keys" in capsys.readouterr().err


def test_a_missing_key_says_how_to_make_one(tmp_path: Path) -> None:
    with pytest.raises(SigningKeyError, match="agrifleet keys SCENARIO --keys"):
        read_key(tmp_path, "t9")


def test_the_keys_command_makes_one_per_vehicle(tmp_path: Path, capsys) -> None:
    assert main(["keys", str(DATA / "tiny.toml"), "--keys", str(tmp_path / "k")]) == 0
    ids = [v.id for v in load_scenario(DATA / "tiny.toml").vehicles]
    for vid in ids:
        assert len(read_key(tmp_path / "k", vid)) == 32
    assert f"{len(ids)} new key(s)" in capsys.readouterr().out
    assert main(["keys", str(DATA / "tiny.toml"), "--keys", str(tmp_path / "k")]) == 0
    assert "0 new key(s)" in capsys.readouterr().out


def test_serve_without_keys_refuses_to_start_unsigned_by_accident(tmp_path: Path, capsys) -> None:
    code = main(["serve", str(DATA / "tiny.toml"), "--data-dir", str(tmp_path)])
    assert code == 2
    err = capsys.readouterr().err
    assert "no MAVLink signing keys" in err and "--unsigned" in err and "tiny.toml" in err


def test_a_restarted_dispatcher_ahead_of_the_clock_still_takes_a_vehicle_met_anew(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """After a restart the dispatcher's own timestamps start from the mark its store kept,
    up to a minute ahead of the clock; a vehicle's stream, new to it, must still pass (and
    a frame recorded an hour ago must not)."""
    key = os.urandom(32)
    vehicle = mc.Codec(11, 1, key=key)
    restarted = mc.Codec(255, 190, key=key, timestamp=mc.signing_timestamp() + 60 * 100_000)
    assert restarted.decode_one(vehicle.encode(heartbeat())) is not None
    now = time.time()
    monkeypatch.setattr(time, "time", lambda: now - 3600.0)
    recorded = mc.Codec(11, 1, key=key).encode(heartbeat())
    monkeypatch.setattr(time, "time", lambda: now)
    assert mc.Codec(255, 190, key=key).decode_one(recorded) is None


def test_a_long_running_sender_is_still_taken_by_a_receiver_that_meets_it_anew(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A restarted dispatcher meets a tractor that has been signing for hours: the
    tractor's timestamps follow the clock, so its stream is not taken for an old one."""
    key = os.urandom(32)
    vehicle = mc.Codec(11, 1, key=key)
    vehicle.encode(heartbeat())
    later = time.time() + 3600.0
    monkeypatch.setattr(time, "time", lambda: later)
    frame = vehicle.encode(heartbeat())
    assert mc.Codec(255, 190, key=key).decode_one(frame) is not None


def test_frames_out_of_order_are_taken_once_each_and_replays_are_not() -> None:
    """A radio that delivers frames out of order loses none of them to the replay check;
    each is still taken at most once, and one older than the window is refused."""
    key = os.urandom(32)
    sender, receiver = mc.Codec(11, 1, key=key), mc.Codec(255, 190, key=key)
    frames = [sender.encode(heartbeat()) for _ in range(5)]
    for frame in (frames[0], frames[3], frames[1], frames[4], frames[2]):
        assert receiver.decode_one(frame) is not None
    assert all(receiver.decode_one(frame) is None for frame in frames)  # each once
    old = mc.Codec(11, 1, key=key)
    old_frame = old.encode(heartbeat())
    ahead = mc.Codec(11, 1, key=key, timestamp=mc.signing_timestamp() + 3 * mc.REORDER_WINDOW)
    assert receiver.decode_one(ahead.encode(heartbeat())) is not None
    assert receiver.decode_one(old_frame) is None  # behind the window


def test_a_frame_of_ours_sent_again_is_told_from_one_signed_anew() -> None:
    """A captured frame of the dispatcher's published again (no key needed) is a replay,
    which the vehicle refuses; a frame signed anew with the key (leaked) is not: the
    alarm says which (a replay was called a leaked key)."""
    from dispatcher.daemon import events as ev

    key = os.urandom(32)
    dispatcher = mc.Codec(255, 190, key=key, link_id=3)
    ours = dispatcher.encode(heartbeat())
    dispatcher.encode(heartbeat())
    assert mc.frame_signature(ours) is not None and dispatcher.sent_before(ours)
    leaked = mc.Codec(255, 190, key=key, link_id=3, timestamp=dispatcher.timestamp + 10)
    assert not dispatcher.sent_before(leaked.encode(heartbeat()))
    # Signed anew a little behind the dispatcher's last (within the vehicle's reordering
    # window, which takes it): a leaked key too, not a replay (it was called one: review).
    behind = mc.Codec(255, 190, key=key, link_id=3)
    behind._mav.signing.timestamp = dispatcher.timestamp - mc.REORDER_WINDOW // 2
    frame = heartbeat().pack(behind._mav)  # as a forger signs it: no clock to follow
    assert mc.frame_signature(frame)[1] < dispatcher.timestamp  # type: ignore[index]
    assert not dispatcher.sent_before(frame)
    other_link = mc.Codec(255, 190, key=key, link_id=9)  # its own stream: taken as new
    assert not dispatcher.sent_before(other_link.encode(heartbeat()))
    assert not dispatcher.sent_before(mc.Codec(255, 190).encode(heartbeat()))  # unsigned
    said = ev.ForeignCommand("v1", "HEARTBEAT", 255, signed=True, replayed=True).text()
    assert "a replay of one of ours" in said and "leaked" not in said
