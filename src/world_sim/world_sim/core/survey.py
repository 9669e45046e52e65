"""The online survey: clusters re-estimated from where the MSDs are, with ids that follow them.

Clusters are found by DBSCAN (scikit-learn): it needs no count of clusters, so an arriving group becomes
a cluster of its own and a group that left stops being one, and the odd MSD between groups is left
unclustered rather than pulling a centroid. Ids are kept by tracking, not relabelled at each survey: the
new clusters are matched to the last survey's by the Hungarian method (scipy's linear_sum_assignment) on
centroid distance, within a gate of the two clusters' radii; an unmatched new cluster takes a new id, an
unmatched old one ends (size 0). Two tracked clusters that DBSCAN finds as one are kept apart (`separate`):
crowds that meet stay two clusters. docs/dynamics.md gives the reasons for the constants.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
from numpy.typing import NDArray
from scipy.cluster.vq import ClusterError, kmeans2
from scipy.optimize import linear_sum_assignment

from .physics import survey_radii

EPS = 10.0            # m: DBSCAN's neighbourhood radius
MIN_SAMPLES = 10      # MSDs within EPS that make a core point (5 chained dense neighbours into one)
MIN_SIZE = 20         # fewer MSDs than this are stragglers, not a cluster to serve
GATE_MARGIN = 10.0    # m added to the two radii within which a new cluster continues an old one
# What the survey reports changes only when it matters: a cluster is reported anew when its centroid or
# radius moved by more than SETTLE_M or its velocity by more than SETTLE_MPS since last reported. Without
# it, users that merely wander jitter the centroids at every survey, and where two spanning trees are of
# nearly equal length the MAPs' tree flips back and forth, moving whole relay chains (docs/dynamics.md).
SETTLE_M = 2.0
SETTLE_MPS = 0.25
SEPARATE_ITER = 10    # k-means iterations that split a found cluster among the tracks it holds
MAX_IDS = 63          # ids a run may use (the agents' achieved-goal masks hold 63 clusters)
NONE = -1             # label of an MSD in no cluster


@dataclass(frozen=True)
class Tracks:
    """Every cluster id a run has used: row = id. An ended cluster keeps its last centroid, with size 0."""

    centroids: NDArray[np.float64]   # (T, 2) m
    radii: NDArray[np.float64]       # (T,) R_k, 95 % radius (m); 0 once ended
    sizes: NDArray[np.intp]          # (T,) MSDs; 0 once ended
    velocities: NDArray[np.float64]  # (T, 2) m/s: centroid shift since the last survey over its period; 0 if new

    @property
    def active(self) -> NDArray[np.bool_]:
        return self.sizes > 0

    def same(self, other: 'Tracks') -> bool:
        return all(np.array_equal(a, b) for a, b in
                   zip((self.centroids, self.radii, self.sizes, self.velocities),
                       (other.centroids, other.radii, other.sizes, other.velocities)))


def find_clusters(xy: NDArray[np.float64]) -> NDArray[np.intp]:
    """DBSCAN labels 0..C-1 (in order of each cluster's first MSD) or NONE; groups under MIN_SIZE are NONE."""
    if len(xy) < MIN_SIZE:
        return np.full(len(xy), NONE, dtype=np.intp)
    from sklearn.cluster import DBSCAN  # here, not at the top: every command that reads a run imports this module
    labels = DBSCAN(eps=EPS, min_samples=MIN_SAMPLES).fit_predict(xy).astype(np.intp)
    found = labels[labels >= 0]
    big = np.flatnonzero(np.bincount(found, minlength=labels.max() + 1) >= MIN_SIZE) if len(found) else []
    remap = np.full(labels.max() + 2, NONE, dtype=np.intp)
    remap[np.asarray(big, dtype=np.intp)] = np.arange(len(big))
    return remap[labels]  # labels == -1 index remap[-1], which is NONE


def _discs(xy: NDArray[np.float64], found: NDArray[np.intp], n: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Centroid and 95 % radius of each of the n labelled clusters."""
    cen = np.array([xy[found == j].mean(axis=0) for j in range(n)]).reshape(-1, 2)
    return cen, (survey_radii(xy, found, cen) if n else np.zeros(0))


def separate(xy: NDArray[np.float64], found: NDArray[np.intp], previous: Optional[Tracks],
             period: float) -> NDArray[np.intp]:
    """found, with each cluster that holds the predicted centroids of two or more live tracks split among them.

    DBSCAN chains two crowds into one once their tails touch, centred on the empty ground between them; the
    tracker then ended one id, and the MAPs re-planned the tree around a cluster that was not there. A
    track is predicted where its velocity takes it in one period; it is held by the found cluster whose
    centroid is nearest among those whose 95 % radius plus GATE_MARGIN reaches it (the margin: a split of two
    crowds head-on can turn their parts across the line they walk, and the velocities measured off the
    turned parts put a prediction just past the radius; the matching's gate has the same margin).
    The held cluster's MSDs are split by k-means (scipy's kmeans2, seeded at the predictions; single-threaded,
    so every process splits alike), unless a part would be smaller than MIN_SIZE. New parts take labels after
    the found ones.
    """
    n = int(found.max()) + 1 if len(found) else 0
    live = np.flatnonzero(previous.active) if previous is not None else np.zeros(0, np.intp)
    if n == 0 or len(live) < 2:
        return found
    pred = previous.centroids[live] + previous.velocities[live] * period
    cen, rad = _discs(xy, found, n)
    dist = np.linalg.norm(pred[:, None, :] - cen[None, :, :], axis=-1)
    within = dist <= rad[None, :] + GATE_MARGIN
    host = np.where(within.any(axis=1), np.argmin(np.where(within, dist, np.inf), axis=1), NONE)
    out, label = found.copy(), n
    for j in range(n):
        held = np.flatnonzero(host == j)
        if len(held) < 2:
            continue
        members = np.flatnonzero(found == j)
        try:
            _, part = kmeans2(xy[members], pred[held], iter=SEPARATE_ITER, minit='matrix', missing='raise')
        except ClusterError:  # a prediction no MSD is nearest to: nothing to split off for it
            continue
        if np.bincount(part, minlength=len(held)).min() < MIN_SIZE:
            continue
        for k in range(1, len(held)):
            out[members[part == k]] = label
            label += 1
    return out


def survey(xy: NDArray[np.float64], previous: Optional[Tracks], period: float) -> tuple[Tracks, NDArray[np.intp]]:
    """(the tracks after this survey, each MSD's cluster id or NONE) from the MSDs' positions xy (M, 2),
    period s after the previous survey."""
    found = separate(xy, find_clusters(xy), previous, period)
    n = int(found.max()) + 1 if len(found) else 0
    cen, rad = _discs(xy, found, n)
    size = np.bincount(found[found >= 0], minlength=n)
    if previous is None:
        previous = Tracks(np.zeros((0, 2)), np.zeros(0), np.zeros(0, np.intp), np.zeros((0, 2)))
    ids = np.full(n, NONE, dtype=np.intp)
    live = np.flatnonzero(previous.active)
    if n and len(live):
        dist = np.linalg.norm(cen[:, None, :] - previous.centroids[live][None, :, :], axis=-1)
        gate = rad[:, None] + previous.radii[live][None, :] + GATE_MARGIN
        rows, cols = linear_sum_assignment(np.where(dist <= gate, dist, 1e9))
        ok = dist[rows, cols] <= gate[rows, cols]
        ids[rows[ok]] = live[cols[ok]]
    centroids, radii = previous.centroids.copy(), np.zeros(len(previous.sizes))
    sizes, velocities = np.zeros(len(previous.sizes), dtype=np.intp), np.zeros((len(previous.sizes), 2))
    for j in range(n):
        if ids[j] == NONE:
            ids[j] = _new_id(set(ids.tolist()), len(centroids))
            if ids[j] == len(centroids):
                centroids, radii = np.vstack([centroids, cen[j]]), np.r_[radii, 0.0]
                sizes, velocities = np.r_[sizes, 0], np.vstack([velocities, np.zeros(2)])
        else:
            velocities[ids[j]] = (cen[j] - previous.centroids[ids[j]]) / period
        centroids[ids[j]], radii[ids[j]], sizes[ids[j]] = cen[j], rad[j], size[j]
    labels = np.where(found >= 0, ids[np.maximum(found, 0)] if n else NONE, NONE).astype(np.intp)
    return Tracks(centroids, radii, sizes.astype(np.intp), velocities), labels


def settle(reported: Optional[Tracks], fresh: Tracks) -> Tracks:
    """What to report after a survey: each cluster as last reported unless it appeared, ended or changed by
    more than the SETTLE_ thresholds, in which case as just surveyed."""
    if reported is None:
        return fresh
    out = Tracks(fresh.centroids.copy(), fresh.radii.copy(), fresh.sizes.copy(), fresh.velocities.copy())
    for k in range(min(len(reported.sizes), len(fresh.sizes))):
        if (reported.sizes[k] > 0) == (fresh.sizes[k] > 0) and \
                np.linalg.norm(fresh.centroids[k] - reported.centroids[k]) <= SETTLE_M and \
                abs(fresh.radii[k] - reported.radii[k]) <= SETTLE_M and \
                np.linalg.norm(fresh.velocities[k] - reported.velocities[k]) <= SETTLE_MPS:
            out.centroids[k], out.radii[k] = reported.centroids[k], reported.radii[k]
            out.sizes[k], out.velocities[k] = reported.sizes[k], reported.velocities[k]
    return out


def _new_id(taken: set[int], used: int) -> int:
    """The next id never used, or once MAX_IDS are used, the lowest id no cluster of this survey holds."""
    if used < MAX_IDS:
        return used
    free = [i for i in range(MAX_IDS) if i not in taken]
    if not free:
        raise ValueError(f'the survey found more than {MAX_IDS} clusters at once')
    return free[0]
