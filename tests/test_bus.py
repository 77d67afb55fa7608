"""Two real Zenoh peers on loopback (scouting off): frames, bad frames, liveliness."""

import numpy as np

from camnet.bus import keys
from camnet.bus.frame import ENCODINGS, encode_frame
from camnet.bus.receiver import FrameReceiver
from camnet.bus.session import declare_liveliness
from tests.conftest import matched_publisher, wait_for
from tests.test_frame import _malformed, make_frame


def test_frames_cross_the_bus_bit_exact(zenoh_pair):
    a, b = zenoh_pair
    receiver = FrameReceiver()
    got = []
    sub = b.declare_subscriber(keys.all_frames("t"),
                               lambda s: got.append(receiver.accept(s.payload.to_bytes())))
    publisher = matched_publisher(a, keys.frame("t", "c0"))
    sent = [make_frame(enc, seq=i, camera_id="c0", h=1024, w=1280)
            for i, enc in enumerate(sorted(ENCODINGS))]
    for frame in sent:
        publisher.put(encode_frame(frame))
    assert wait_for(lambda: len(got) == len(sent))
    for frame, back in zip(sent, got, strict=True):
        assert back.encoding == frame.encoding
        assert np.array_equal(back.image, frame.image)
    sub.undeclare()


def test_bad_frames_do_not_stop_the_subscriber(zenoh_pair):
    a, b = zenoh_pair
    receiver = FrameReceiver()
    good = []

    def on_sample(sample):
        frame = receiver.accept(sample.payload.to_bytes())
        if frame is not None:
            good.append(frame.seq)

    sub = b.declare_subscriber(keys.all_frames("t"), on_sample)
    publisher = matched_publisher(a, keys.frame("t", "c1"))
    bad = _malformed()
    seqs = [0, 1, 2, 4, 5, 9]
    for seq in seqs:
        for payload in bad.values():
            publisher.put(payload)
        publisher.put(encode_frame(make_frame("mono8", seq=seq, camera_id="c1")))
    assert wait_for(lambda: len(good) == len(seqs))
    assert good == seqs
    assert receiver.malformed.counts == {kind: len(seqs) for kind in bad}
    assert receiver.counts()["c1"].dropped == 4
    sub.undeclare()


def test_liveliness_token_is_seen_and_goes_away(zenoh_pair):
    a, b = zenoh_pair
    key = keys.node("t", "driver", "c2")
    token = declare_liveliness(a, key)

    def live():
        return [str(r.ok.key_expr) for r in b.liveliness().get(keys.all_nodes("t"), timeout=1.0)
                if r.ok is not None]

    assert wait_for(lambda: live() == [key])
    token.undeclare()
    assert wait_for(lambda: live() == [])


def test_receiver_counts_what_crosses_the_bus(zenoh_pair):
    a, b = zenoh_pair
    receiver = FrameReceiver()
    sub = b.declare_subscriber(keys.frame("t", "c3"), lambda s: receiver.accept(s.payload.to_bytes()))
    publisher = matched_publisher(a, keys.frame("t", "c3"))
    for seq in range(6):
        publisher.put(encode_frame(make_frame("mono8", seq=seq, camera_id="c3")))
    assert wait_for(lambda: receiver.counts().get("c3") is not None
                    and receiver.counts()["c3"].received == 6)
    assert receiver.counts()["c3"].last_seq == 5
    assert receiver.counts()["c3"].dropped == 0
    sub.undeclare()
