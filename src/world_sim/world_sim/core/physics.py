"""Ground users, association (eq. 2), coverage (eq. 5), the MAP graph (eq. 4) and the dynamics (eq. 3)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import eigh
from scipy.sparse import coo_matrix, diags
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import ArpackNoConvergence, eigsh
from scipy.spatial import cKDTree

from .scenario import Scenario

F64 = NDArray[np.float64]
UNSERVED = -1


@dataclass(frozen=True)
class Users:
    """The MSDs of a run: positions on the ground (z = 0) and the cluster each was drawn from."""

    xyz: F64                # (M, 3)
    cluster: NDArray[np.intp]  # (M,) the cluster each MSD belongs to, or -1 (the online survey's stragglers)
    centroids: F64          # (K, 2): the empirical centroid C_k of each cluster
    radii: F64 | None = None  # (K,): radius R_k about C_k holding 95 % of cluster k's MSDs (m)

    @property
    def cluster_sizes(self) -> NDArray[np.intp]:
        return np.bincount(self.cluster[self.cluster >= 0], minlength=len(self.centroids))


def streams(seed: int) -> dict[str, np.random.Generator]:
    """Independent random streams per purpose, so e.g. a failure fraction never moves the users."""
    # A child's draws do not depend on how many are spawned: each new purpose came last and moved none before it.
    users, release, failure, walk, vehicle = np.random.SeedSequence(seed).spawn(5)
    return {'users': np.random.default_rng(users), 'release': np.random.default_rng(release),
            'failure': np.random.default_rng(failure), 'walk': np.random.default_rng(walk),
            'vehicle': np.random.default_rng(vehicle)}


def make_users(s: Scenario, rng: np.random.Generator) -> Users:
    """Gaussian clusters of MSDs (Section V)."""
    xy, label = [], []
    for k, c in enumerate(s.clusters):
        xy.append(rng.normal(c.center, c.spread, size=(c.size, 2)))
        label.append(np.full(c.size, k, dtype=np.intp))
    xy_all = np.concatenate(xy)
    labels = np.concatenate(label)
    centroids = np.array([xy_all[labels == k].mean(axis=0) for k in range(len(s.clusters))])
    return Users(np.column_stack([xy_all, np.zeros(len(xy_all))]), labels, centroids,
                 survey_radii(xy_all, labels, centroids))


def label_centroids(xy: F64, cluster: NDArray[np.intp]) -> dict[int, F64]:
    """C_k of each cluster that has MSDs (label >= 0): the mean of their positions, by ascending label."""
    return {int(k): xy[cluster == k].mean(axis=0) for k in np.unique(cluster[cluster >= 0])}


def survey_radii(xy: F64, cluster: NDArray[np.intp], centroids: F64) -> F64:
    """R_k: the 95th percentile of cluster k's MSDs' distances from C_k (what the aerial survey reports)."""
    return np.array([np.percentile(np.linalg.norm(xy[cluster == k] - centroids[k], axis=1), 95.0)
                     if np.any(cluster == k) else 0.0 for k in range(len(centroids))])


def release(s: Scenario, rng: np.random.Generator) -> tuple[F64, F64]:
    """Initial q and p: uniform in a square around the release centre at height H, p uniform in [-v, v]^2."""
    n = s.maps
    xy = np.asarray(s.release_center) + rng.uniform(-s.release_half_width, s.release_half_width, size=(n, 2))
    q = np.column_stack([xy, np.full(n, s.flock.height)])
    v = rng.uniform(-s.initial_speed, s.initial_speed, size=(n, 2))
    p = np.column_stack([v, np.zeros(n)])
    return q, p


def failure_ids(s: Scenario, alive_ids: NDArray[np.intp], rng: np.random.Generator) -> NDArray[np.intp]:
    """The MAP ids that fail at s.fail_at: round(fraction * alive) of them, drawn from the failure stream."""
    count = int(round(s.fail_fraction * len(alive_ids)))
    return np.sort(rng.choice(np.asarray(alive_ids), size=count, replace=False)) if count else np.zeros(0, np.intp)


def associate(users: Users, q: F64, r: float, mode: str = '3d') -> NDArray[np.intp]:
    """Eq. 2: each MSD joins the MAP with the strongest signal rho*||y - q||^-eta among those within r.

    For any rho, eta > 0 (the scenario checks both) the signal falls with distance, so that is the nearest
    MAP in range, found without rho and eta; returns its row in q, or UNSERVED.
    """
    if len(q) == 0:
        return np.full(len(users.xyz), UNSERVED, dtype=np.intp)
    if mode == 'horizontal':
        tree, pts = cKDTree(q[:, :2]), users.xyz[:, :2]
    else:
        tree, pts = cKDTree(q), users.xyz
    dist, idx = tree.query(pts, k=1, distance_upper_bound=np.nextafter(r, np.inf))
    return np.where(np.isfinite(dist), idx, UNSERVED).astype(np.intp)


def user_counts(assoc: NDArray[np.intp], n_maps: int) -> NDArray[np.intp]:
    """N_u for each MAP row."""
    served = assoc[assoc != UNSERVED]
    return np.bincount(served, minlength=n_maps)


def cluster_coverage(users: Users, assoc: NDArray[np.intp]) -> F64:
    """Fraction of each cluster's MSDs that are served: r_g when the cluster is a MAP's goal."""
    served = np.bincount(users.cluster[(assoc != UNSERVED) & (users.cluster >= 0)], minlength=len(users.centroids))
    return served / np.maximum(users.cluster_sizes, 1)


def coverage_ratio(assoc: NDArray[np.intp]) -> float:
    """R_c of eq. 5."""
    return float(np.count_nonzero(assoc != UNSERVED)) / max(len(assoc), 1)


def neighbour_pairs(q: F64, r: float) -> NDArray[np.intp]:
    """Ordered pairs (i, j), i != j, with ||q_i - q_j|| <= r (eq. 4), sorted by i then j."""
    if len(q) < 2:
        return np.zeros((0, 2), dtype=np.intp)
    pairs = cKDTree(q).query_pairs(np.nextafter(r, np.inf), output_type='ndarray')
    both = np.concatenate([pairs, pairs[:, ::-1]]).astype(np.intp)
    order = np.lexsort((both[:, 1], both[:, 0]))
    return both[order]


# Peak bytes per unordered pair within r while neighbour_pairs works: the tree's pairs, both orders, their sorted copy.
PAIR_BYTES = 96


def release_pairs(n: int, half_width: float, r: float) -> float:
    """Expected unordered MAP pairs within r at release: n uniform in a square of side L = 2 * half_width.

    P(|a - b| <= r) for two uniform points of a square of side L >= r is (pi r^2 L^2 - 8/3 r^3 L + r^4 / 2) / L^4
    (the square's distance distribution); beyond L, 1 bounds it.
    """
    side = 2.0 * half_width
    p = 1.0 if r >= side else (np.pi * r**2 * side**2 - 8.0 / 3.0 * r**3 * side + r**4 / 2.0) / side**4
    return n * (n - 1) / 2.0 * min(p, 1.0)


def laplacian(pairs: NDArray[np.intp], n: int) -> F64:
    """L = D - A of the MAP graph from its ordered pairs."""
    a = np.zeros((n, n))
    a[pairs[:, 0], pairs[:, 1]] = 1.0
    return np.diag(a.sum(axis=1)) - a


def component_labels(pairs: NDArray[np.intp], n: int) -> NDArray[np.intp]:
    """Each MAP's connected component of the MAP graph, numbered from 0; which MAPs a split cuts off."""
    a = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(a, directed=False)[1].astype(np.intp)


def components(pairs: NDArray[np.intp], n: int) -> int:
    return 0 if n == 0 else int(component_labels(pairs, n).max()) + 1


SPARSE_FROM = 500  # MAPs: above, lambda2 from the sparse Laplacian (at 993 MAPs 8-16 ms a step against 65-180 ms) ...
SPARSE_DEGREE = 50  # ... when its mean degree is no more: a packed release square (degree 140-170) factors slower ...
DENSE_UNTIL = 1500  # ... except above this many MAPs, whatever the degree: at 2000 MAPs packed (degree 426) 0.6 s
                    # against 8.5 s dense, at 5000 (degree 1079) 10 s, where the dense solver took minutes
_SHIFT = 1e-2      # L + _SHIFT I is positive definite: its LU is what shift-invert solves with


def fiedler(pairs: NDArray[np.intp], n: int, n_components: int | None = None) -> float:
    """Second-smallest Laplacian eigenvalue; exactly 0 when the graph is disconnected (or n < 2)."""
    if n < 2:
        return 0.0
    if n_components is None:
        n_components = components(pairs, n)
    if n_components > 1:
        return 0.0
    sparse = n > DENSE_UNTIL or (n > SPARSE_FROM and len(pairs) <= SPARSE_DEGREE * n)
    value = _sparse_fiedler(pairs, n) if sparse else None
    if value is None:
        value = eigh(laplacian(pairs, n), eigvals_only=True, subset_by_index=[1, 1])[0]
    return float(max(value, 0.0))


def _sparse_fiedler(pairs: NDArray[np.intp], n: int) -> float | None:
    """lambda2 of a connected graph by shift-invert Lanczos (ARPACK): the two eigenvalues nearest -_SHIFT are the
    two smallest, 0 and lambda2; equal to the dense value to about 1e-11 relative. The start vector is fixed,
    so every process computes the same bits; None if ARPACK does not converge (the dense solver then does)."""
    a = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n)).tocsr()
    lap = (diags(np.asarray(a.sum(axis=1)).ravel()) - a).tocsc()
    start = np.random.default_rng(0).random(n)
    try:
        values = eigsh(lap, k=2, sigma=-_SHIFT, which='LM', tol=0, v0=start, return_eigenvectors=False)
    except ArpackNoConvergence:
        return None
    return float(np.sort(values)[1])


def least_distance(q: F64, pairs: NDArray[np.intp] | None = None) -> float:
    """The least distance between two of these positions (m); NaN for fewer than two. pairs: those within some
    range, when known (neighbour_pairs): the nearest two are among them if any is, and measured there alone."""
    if len(q) < 2:
        return float('nan')
    if pairs is not None and len(pairs):
        once = pairs[pairs[:, 0] < pairs[:, 1]]  # each pair once, not both ways
        d = q[once[:, 1]] - q[once[:, 0]]
        return float(np.sqrt((d * d).sum(axis=1).min()))  # the root of the least square: the same bits
    return float(cKDTree(q).query(q, k=2)[0][:, 1].min())


def integrate(q: F64, p: F64, u: F64, dt: float) -> tuple[F64, F64]:
    """Exact zero-order-hold step of the double integrator q' = p, p' = u (eq. 3) with u held over dt."""
    return q + p * dt + 0.5 * u * dt * dt, p + u * dt
