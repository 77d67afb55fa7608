"""The observations message of a growing track pool as JSON bytes, each track encoded once.

A live pool is published after every frame set that changed it, and encoding
the whole document of a full pool costs the matcher tens of milliseconds a set
(docs/benchmarks.md, "Evidence behind the nodes' choices"). From one publication to the next most tracks are
unchanged: a pooled track keeps its id and pixels until it is evicted, except
that seeing it again may add cameras to it. So `ObservationsEncoder` keeps
each track's JSON text with the pixels it was made from, encodes only the
tracks that are new or whose pixels changed, and joins the pieces.

The bytes are exactly those of `camnet.io.messages.encode_observations_message`:
a consumer cannot tell the two apart.
"""

from __future__ import annotations

import json

import numpy as np

from camnet.io.formats import observations_head_to_doc
from camnet.io.messages import ObservationsMessage, encode_observations_message, observations_envelope_to_doc


class ObservationsEncoder:
    """Encodes successive messages of one pool; keeps the last call's tracks. Not thread-safe."""

    def __init__(self) -> None:
        self._names: tuple[str, ...] = ()
        self._ids = np.empty(0, dtype=np.int64)
        self._bits = np.empty((0, 0), dtype=np.uint64)  # per track, its dense (camera, u/v) pixels' bits
        self._pieces: list[str] = []
        self.encoded = 0  # tracks encoded by the last call (the others came from the cache)

    def encode(self, message: ObservationsMessage) -> bytes:
        """`encode_observations_message(message)`, the tracks unchanged since the last call from the cache."""
        obs = message.observations
        names = tuple(c.id for c in obs.cameras)
        cam = np.asarray(obs.cam_index, dtype=np.int64)
        trk = np.asarray(obs.track_index, dtype=np.int64)
        order = trk * max(len(names), 1) + cam
        uv = np.asarray(obs.uv, dtype=float).reshape(-1, 2)
        if order.size and not (np.all(np.diff(order) > 0) and np.all(np.isfinite(uv))):
            # Not by track then camera as a pool gives them (a track's cameras may come in any order), or
            # pixels JSON spells its own way: encode it all as the codec does.
            self._names, self._ids, self._pieces = (), np.empty(0, dtype=np.int64), []
            self.encoded = len(obs.track_ids)
            return encode_observations_message(message)
        pieces = self._track_pieces(names, np.asarray(obs.track_ids, dtype=np.int64), cam, trk, uv)
        head = json.dumps(observations_head_to_doc(obs))
        text = f'{head[:-1]}, "tracks": [{", ".join(pieces)}]'
        further = observations_envelope_to_doc(message)
        text += f", {json.dumps(further)[1:]}" if further else "}"
        return text.encode()

    def _track_pieces(self, names: tuple[str, ...], ids: np.ndarray, cam: np.ndarray, trk: np.ndarray,
                      uv: np.ndarray) -> list[str]:
        """Each track's JSON text, from the cache where its id and pixels (bit for bit) are unchanged."""
        dense = np.full((len(ids), len(names), 2), np.nan)
        dense[trk, cam] = uv
        bits = dense.reshape(len(ids), -1).view(np.uint64)
        reused = np.zeros(len(ids), dtype=bool)
        previous = np.zeros(len(ids), dtype=np.int64)
        if names == self._names and len(self._ids) and len(ids):
            by_id = np.argsort(self._ids)
            at = np.minimum(np.searchsorted(self._ids[by_id], ids), len(by_id) - 1)
            previous = by_id[at]
            reused = (self._ids[previous] == ids) & np.all(self._bits[previous] == bits, axis=1)
        starts = np.searchsorted(trk, np.arange(len(ids) + 1))
        quoted = [json.dumps(name) for name in names]
        pieces = []
        for t, track_id in enumerate(ids.tolist()):
            if reused[t]:
                pieces.append(self._pieces[previous[t]])
                continue
            first, end = starts[t], starts[t + 1]
            pixels = ", ".join(f"{quoted[c]}: [{u!r}, {v!r}]"
                               for c, (u, v) in zip(cam[first:end].tolist(), uv[first:end].tolist(), strict=True))
            pieces.append(f'{{"id": {track_id!r}, "observations": {{{pixels}}}}}')
        self._names, self._ids, self._bits, self._pieces = names, ids, bits, pieces
        self.encoded = int(len(ids) - reused.sum())
        return pieces
