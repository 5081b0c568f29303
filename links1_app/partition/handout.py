"""How the root hands units out: tasks within a pixel budget and guided chunks (paper 4-3).

Shared by every backend (:mod:`.executors`, :mod:`.local_pool`, :mod:`.dask_backend`) and by
the simulator (:mod:`.simulator`), which replays the same hand-out.
"""
from __future__ import annotations

#: A unit that has killed this many workers is reported as an error (Dask's allowed-failures).
ALLOWED_FAILURES = 3
#: ``dynamic``: a node that asks for work gets ``ceil(remaining / (CHUNK_FACTOR x nodes))``
#: units (guided self-scheduling); ``--chunk-factor 0``: one unit at a time (the paper's 4-3).
CHUNK_FACTOR = 2
#: Pixels one task (a batch of units sent to a node in one message) may hold; the node renders
#: it in as few launches as its memory budget allows (``runtime.LAUNCH_SAMPLES``).
TASK_PIXELS = 1 << 18


def take_batch(plan, queue, max_units=None, max_pixels=TASK_PIXELS):
    """Pop the next units of ``queue`` (a deque of unit indices) for one task: at most
    ``max_units`` units and ``max_pixels`` pixels, at least one unit."""
    out, px = [], 0
    while queue and (max_units is None or len(out) < max_units):
        u = plan.units[queue[0]]
        if out and px + u.w * u.h > max_pixels:
            break
        out.append(queue.popleft())
        px += u.w * u.h
    return out


def chunk_size(remaining, n_nodes, chunk_factor):
    """Guided self-scheduling: units in the next dynamic chunk (1 when ``chunk_factor`` is 0)."""
    if chunk_factor <= 0 or remaining <= 0:
        return 1
    return max(1, -(-remaining // (chunk_factor * max(1, n_nodes))))


def guided_batch(plan, queue, n_nodes, chunk_factor, max_pixels=TASK_PIXELS, by_load=False):
    """The next dynamic chunk: :func:`chunk_size` units (one node: every unit the pixel budget
    allows), or with ``by_load`` (and a plan that
    predicts each unit's load) units up to ``remaining load / (k nodes)`` of predicted load
    (at least one): guided self-scheduling that weighs units, so a chunk of the heaviest
    units (LPT order) is not k x nodes times the work it should be."""
    if n_nodes <= 1 and chunk_factor > 0:
        # one node has nobody to balance with: smaller chunks would only add launches, each
        # paying the renderer's per-launch cost; it takes what the task budget allows
        return take_batch(plan, queue, None, max_pixels)
    pred = getattr(plan, "predicted", None)
    if not by_load or pred is None or chunk_factor <= 0:
        return take_batch(plan, queue, chunk_size(len(queue), n_nodes, chunk_factor), max_pixels)
    target = sum(float(pred[i]) for i in queue) / (chunk_factor * max(1, n_nodes))
    out, load, px = [], 0.0, 0
    while queue:
        u = plan.units[queue[0]]
        p = float(pred[queue[0]])
        if out and (load + p > target or px + u.w * u.h > max_pixels):
            break
        out.append(queue.popleft())
        load += p
        px += u.w * u.h
    return out
