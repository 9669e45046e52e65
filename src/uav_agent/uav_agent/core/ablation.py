"""Rules by name, so that an ablation can switch one off alone (a study's variant `without:`, docs/studies.md;
benchmarks/bench_ablation.py, bench_links.py).

Every rule is on unless a run is flown inside `switched_off`. Each name is the rule's section in
docs/dynamics.md or docs/links.md.
"""
from __future__ import annotations

from contextlib import contextmanager
from contextvars import ContextVar
from typing import Iterable, Iterator

RULES = {
    'carry': 'keys carried across surveys: a role gives up or takes only what its share changed by (keys.carry)',
    'kept': 'kept shares: a role keeps its MAPs down to its share / (1 + SLACK) (layout.kept)',
    'standing': 'make before break: an edge that left the tree keeps its relays (layout.standing); on a lagged vehicle, '
                'with rule nearest, also an edge swapped for one with a cluster in common, whose relays would swing',
    'swing': 'swinging chains: relays of a swapped edge swing about the shared cluster, on the paper\'s vehicle; on a '
             'lagged one the swapped edge stands instead (rule standing), unless rule nearest is off (demand.pivot)',
    'tree': 'along the tree: a MAP in transit flies cluster to cluster (demand.en_route)',
    'chain': 'leaving by the chain: a MAP in transit leaves its disc along the relay chain (demand.leg_aim)',
    'passing': 'passing at d/2: unrelated MAPs in transit repel within d/2 only, but not under the safety filter '
               '(demand.Demand.link)',
    'straight': 'released relays of a standing chain fly straight along it, on the paper\'s vehicle: on a lagged one they '
                'fly along the tree, as other MAPs in transit do (demand.demand_switch)',
    'vacate': 'vacated roles: a role heard of by nobody for VACANT_STEPS is declared lost (vacancy.vacate)',
    'short': 'short roles: a relay that finds its chain taut asks for more MAPs (demand.tally)',
    'offset': 'a relay reaching past the last member it hears on one side reaches r - 1 m in the plane, not along '
              'the edge, under the paper\'s channel (demand._reach_past)',
}
# The channel's (core/ear.heard_from): what a MAP makes of a neighbour state that is not of this step. None of
# them acts under the paper's channel.
CHANNEL_RULES = {
    'predict': 'a stale neighbour state stands for where its sender is now, flown on at its velocity then',
    'gone': 'a neighbour whose state so predicted lies beyond r is taken for gone',
    'inside': 'relay chains laid on links no longer than the channel still delivers half over (demand.reach_of)',
    'hearsay': 'a MAP passes on the states it holds of its nearest neighbours; one heard through them stands for a '
             'neighbour whose own states are lost (ear.Ear.hear_passed)',
    'stay': 'a settled relay that hears no member of its chain under a lossy channel stays where it is along its '
            'edge (demand.relay_place)',
    'hold': 'a relay that hears one side of its chain, or a server no relay of its cluster, for no longer than '
            'the channel\'s losses last takes it for lost states and holds its place (demand.hushed, demand.anchored)',
}
# The vehicle's (core/envelope.py): how a MAP flies eq. 9 within a multirotor's envelope. None of them acts on the
# paper's vehicle.
VEHICLE_RULES = {
    'brake': 'a goal term aims at a speed from which the MAP stops before its goal, within its cruise speed, and a '
             'MAP faster than that brakes back (envelope.capped, envelope.governor)',
    'keep': 'a MAP brakes along a link it closes on faster than it could stop keep m short (envelope.keep_apart)',
    'traffic': "rules keep and swerve act on the position broadcasts a MAP receives within the vehicle's traffic "
               'range (the most urgent eight, vehicle.traffic), not on the neighbours it hears within r',
    'swerve': 'a MAP braking on a link also turns away from where that neighbour will be at their closest approach, '
              'to its right when head-on (envelope.swerve)',
    'lead': "eq. 9's flocking terms taken where the MAPs will be four lags ahead: the damping a lagged link needs "
            '(envelope.flocking_within)',
    'soften': "eq. 9's flocking terms halved on a lagged vehicle (envelope.flocking_within)",
    'shape': "the goal term's spring softened with the flocking terms, so a lattice keeps eq. 9's shape "
             '(envelope.spring)',
    'loose': 'a relay and the servers of its edge only repel, under the demand allocation: the chain rule alone places '
             'the relay (demand.loose)',
    'inline': 'fellow relays of one chain space themselves along their edge only, not in the plane, on a lagged '
              'vehicle under the demand allocation: no zig-zag stores relays sideways (demand.inline)',
    'ends': "a relay that knows its rank in its chain and both anchors, passed on hop by hop, flies to its even "
            'share of the span at once, or lays a chain too short for it out taut from one anchor, and a relay in '
            'transit that hears no member of its chain joins it at the nearer end of its gap, not at its place by key, '
            "on a lagged vehicle under the paper's channel (chain.ends_place, chain.relay_place)",
    'priority': "that braking is served first from a_max, eq. 9's terms from what is left (envelope.command)",
    'links': "the safety filter (policies: {safety: filter}) also keeps a chain's links (fellow relays of one edge, both "
             "sharing it, and a relay and its edge's servers, the relay alone, both settled, once both the chain's clusters "
             "are served: the allocation's needed) shorter than r less a margin, those of the "
             'relative-neighbourhood graph among them, with a slack priced below separation (safety.protected, '
             'safety.link_budget)',
    'release': "the safety filter's liveness: a MAP that a protected link has held back from its goal (farther than "
               'half of d from it) for RELEASE_S without a break protects no link for FREE_S (safety.held_next)',
    'patient': 'a role is declared lost after PATIENT_STEPS unheard of, not VACANT_STEPS, and a chain short after '
               'PATIENT_STEPS found taut, not TAUT_STEPS: a multirotor takes that long to cross to it, under the demand '
               'allocation (vacancy.vacant_steps, chain.taut_steps); but a relay seen to fail (heard well within r, then '
               'nowhere near where it was, under the paper\'s channel) finds its chain one MAP short at once '
               '(vacancy.vanished)',
    'nearest': "a new edge or cluster takes its share first from the clusters nearest it on the tree, down to their "
               'floor, not from the roles most above their share wherever they are, and an edge found short is lent '
               'its MAPs by its own two clusters, and a relay let go from a standing chain joins the nearer of its two '
               'clusters by where it is, under the demand allocation (layout.roles, vacancy.nearest, vacancy.view, '
               'demand.rejoined)',
    'cascade': 'the keys a role of the tree (an arriving cluster first, or an edge to it) takes from a cluster more than '
               'one hop away pass hop by hop: each cluster on the way gives its own to the one before it, so a MAP '
               'crosses one hop, or two past a cluster that gave all its own to an arrival, under rule nearest '
               '(layout.cascaded)',
}
RULES.update(CHANNEL_RULES)
RULES.update(VEHICLE_RULES)
# Per thread of control, not per process: a Dask worker flies runs of different variants on its threads at once.
_OFF: ContextVar[frozenset[str]] = ContextVar('uav_flock_rules_off', default=frozenset())


def on(rule: str) -> bool:
    return rule not in _OFF.get()


def unknown(rules: Iterable[str]) -> list[str]:
    """The names among rules that name no rule, sorted."""
    return sorted(set(rules) - set(RULES))


@contextmanager
def switched_off(rules: Iterable[str]) -> Iterator[None]:
    """Fly what runs inside with these rules off (and every other on); ValueError for a name of no rule."""
    rules = frozenset(rules)
    if unknown(rules):
        raise ValueError(f'{", ".join(unknown(rules))}: not a rule of core/ablation.py')
    token = _OFF.set(rules)
    try:
        yield
    finally:
        _OFF.reset(token)
