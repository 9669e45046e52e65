"""QoS profiles of uav-flock topics, and the sync modes that choose between them, named once for every node."""
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

# Samples every writer keeps: a reader (a neighbour, or the recorder) that is up to this many steps
# behind still gets each one. world_sim keeps the recorder within RECORDER_MAX_LAG_STEPS of the run.
HISTORY_DEPTH = 50
RECORDER_MAX_LAG_STEPS = 16

# State of a MAP, written and read alike: a neighbour that subscribes late gets the recent samples at once,
# the last one last; and the deep reader queue keeps a flood of bad samples from another writer on the
# same topic from evicting the genuine one before the callback has seen it.
STATE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=HISTORY_DEPTH,
                       reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
# Per-step traffic that must not be lost in lockstep: sensing, commands, association, metrics, events.
# Transient-local: DDS matches a writer and a reader from each side on its own, and a reader may see a
# writer (the recorder's "every topic matched", world_sim's "every MAP publishes commands") before that
# writer sees the reader; a volatile writer sends what it publishes meanwhile to no one. A transient-local
# one hands its kept samples to each transient-local reader as it matches it, so none is lost; a reader
# takes a handed-over sample of a past step for the late copy it is.
STEP_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=HISTORY_DEPTH,
                      reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
# Fixed for a run (users, clusters): latched.
LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)

# lockstep: every step waits for every MAP (deterministic); realtime: the world steps on a wall clock.
SYNC_MODES = ('lockstep', 'realtime')


def is_realtime(sync: str) -> bool:
    """The `sync` parameter of a node, checked: a wrong value is the user's mistake (ValueError)."""
    if sync not in SYNC_MODES:
        raise ValueError(f"parameter sync: expected one of {', '.join(SYNC_MODES)}, got {sync!r}")
    return sync == 'realtime'

# realtime: a reader that falls behind skips to the newest sample instead of working through old ones,
# as a flight computer reads the latest fix, not a backlog.
LATEST_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)
LATEST_STATE_READ_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                   durability=DurabilityPolicy.TRANSIENT_LOCAL)
