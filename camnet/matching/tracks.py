"""Chain pairwise matches of one frame set into multi-view tracks.

Nodes are (camera, keypoint); every verified match joins two nodes. A track
is a connected component (the closure a union-find would give). A component
that holds two different keypoints of one camera is inconsistent, since a
scene point has one image per camera, and is dropped whole: which of its
matches is wrong cannot be told from the graph alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from camnet.matching.features import FrameSetMatches


@dataclass(frozen=True)
class FrameTracks:
    """Tracks of one frame set.

    ``uv[k, c]`` is the pixel (u right, v down, origin at the centre of the
    top-left pixel) of track k in camera ``camera_ids[c]``, NaN where the
    camera does not see it. Every track is seen by at least 2 cameras.
    """

    camera_ids: tuple[str, ...]
    uv: np.ndarray  # (T, C, 2) float pixels, NaN = unseen
    dropped_inconsistent: int = 0  # components removed for a camera seen twice

    def __len__(self) -> int:
        return self.uv.shape[0]

    @property
    def views(self) -> np.ndarray:
        """(T,) number of cameras that see each track."""
        return np.isfinite(self.uv[:, :, 0]).sum(axis=1)


def build_tracks(matches: FrameSetMatches, *, min_views: int = 2) -> FrameTracks:
    """Tracks from the verified pairwise matches of one frame set.

    Keeps consistent components seen by at least `min_views` cameras.
    """
    n_cams = len(matches.camera_ids)
    sizes = np.array([len(f) for f in matches.features], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    n_nodes = int(offsets[-1])
    src = [offsets[p.a] + p.index_a for p in matches.pairs]
    dst = [offsets[p.b] + p.index_b for p in matches.pairs]
    src_all = np.concatenate(src) if src else np.empty(0, dtype=np.int64)
    dst_all = np.concatenate(dst) if dst else np.empty(0, dtype=np.int64)
    empty = FrameTracks(matches.camera_ids, np.empty((0, n_cams, 2)))
    if src_all.size == 0:
        return empty
    graph = coo_matrix((np.ones(src_all.size, dtype=np.int8), (src_all, dst_all)), shape=(n_nodes, n_nodes))
    _, label = connected_components(graph, directed=False)
    used = np.unique(np.concatenate([src_all, dst_all]))
    used_label = label[used]
    used_cam = np.searchsorted(offsets, used, side="right") - 1
    used_kp = used - offsets[used_cam]

    # Inconsistent: a component with more than one node in the same camera.
    comp, comp_of_node = np.unique(used_label, return_inverse=True)
    per_cam = np.zeros((comp.size, n_cams), dtype=np.int64)
    np.add.at(per_cam, (comp_of_node, used_cam), 1)
    consistent = per_cam.max(axis=1) <= 1
    views = (per_cam > 0).sum(axis=1)
    keep = consistent & (views >= min_views)

    track_of_comp = np.full(comp.size, -1, dtype=np.int64)
    track_of_comp[keep] = np.arange(int(keep.sum()))
    uv = np.full((int(keep.sum()), n_cams, 2), np.nan)
    node_track = track_of_comp[comp_of_node]
    sel = node_track >= 0
    for c in range(n_cams):
        in_cam = sel & (used_cam == c)
        uv[node_track[in_cam], c] = matches.features[c].uv[used_kp[in_cam]]
    return FrameTracks(matches.camera_ids, uv, int((~consistent).sum()))
