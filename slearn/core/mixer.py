"""How the contexts of one prediction are weighed: exponential weights over experts.

For one view (one observation channel), the candidates of a prediction are the
contexts of length ``1..K`` found in the tree. Each context offers three *experts*:

* ``FREQUENT``: its outcome seen most often (all time);
* ``RECENT``: its outcome seen last;
* ``FRESH``: its outcome seen most often since the view's current epoch began.

An expert is ``(context length, kind)``; experts whose context was never seen sleep.
The awake expert of largest weight speaks (Hedge with sleeping experts, Freund et al.
1997): after the outcome, every awake expert that was wrong loses ``ETA`` of log-weight
(its weight is multiplied by ``exp(-ETA)``), then the awake experts' total is restored,
so sleeping experts neither gain nor lose.
Weights stay within ``SPREAD`` of the leader, so an expert that was poor for a long
time can take over after a few dozen mistakes of the leader: the mixture tracks the best
expert when it changes (a switch of dynamics), as fixed-share does.

Epochs. Counts accumulated before a change of dynamics mislead frequency forever. Bernoulli
CUSUM tests (Page 1954) watch the most trusted frequency expert: each of its predictions
has its own hit probability ``p`` (PPM's method C: the outcome's count over the context's
total plus one escape count per distinct outcome), and test ``i`` accumulates the
log-likelihood ratio of "the hit probability dropped to ``p / DROPS[i]``" against ``p``, so a
miss where the context is nearly certain weighs much, a miss where it is a coin toss
little. One test per drop in :data:`DROPS` (halved, as a slow drift does; near zero, as a
reversal does) detects each kind of change about as fast as a test built for it alone.
An alarm is raised when a test passes ``ln(len(DROPS) / FALSE_ALARM)`` (so the false-alarm
rate per prediction of all tests together is at most ``FALSE_ALARM`` when the shares are
calibrated). An alarm opens a new epoch, which starts at the alarming test's estimate of
the change point (the step after its statistic was last zero, Page's estimate): fresh
counts restart from the occurrences since then (:func:`slearn.core.context_tree.seed_fresh`),
and the ``FRESH`` experts start from the weights of the frequency experts of the same
length, so they speak as soon as they are as good. A false alarm costs little, because
the all-time experts keep their weights.

Ties go to ``FRESH``, then ``RECENT``, then shorter contexts: with no evidence yet, the
latest and simplest explanation speaks. No constant is tuned to a data set:
``ETA`` is Hedge's rate for tens of experts over ~10^4 predictions, ``SPREAD`` bounds the
catch-up to ``SPREAD / ETA`` net mistakes, ``FALSE_ALARM`` is a rate and ``DROPS`` a
geometric grid of alternatives; the measured tables in ``bench/`` are flat over a factor
of two in each.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from slearn.core._jit import helper

FREQUENT, RECENT, FRESH = 0, 1, 2
KINDS = ("frequent", "recent", "fresh")
N_KINDS = 3
ETA = 0.1
SPREAD = 5.0
FALSE_ALARM = 1e-6
_BETA = float(np.exp(-ETA))
_FLOOR = float(np.exp(-SPREAD))
_TIE = np.array([1.0, 1.0 + 2e-9, 1.0 + 4e-9])  # prior weight per kind: FRESH, then RECENT, win ties
ASLEEP = 0.0  # the weight of FRESH experts before the first epoch
DROPS = (2.0, 8.0, 32.0)  # the tests' alternatives: the expert's hit probability over each
N_TESTS = len(DROPS)
# a view's detector: per test its statistic, per test the clock after its last zero, then
# misses and trials since the epoch began, and the clock the epoch began at
CUSUM, CALM = 0, N_TESTS
MISSES, TRIALS, START = 2 * N_TESTS, 2 * N_TESTS + 1, 2 * N_TESTS + 2
DETECTOR_FIELDS = 2 * N_TESTS + 3
CLOCK_FIELDS = (*range(CALM, CALM + N_TESTS), START)
_THRESHOLD = float(np.log(N_TESTS / FALSE_ALARM))
_DROPS = np.array(DROPS)


class Mixer(NamedTuple):
    """Expert weights and change detectors of all views.

    ``weight[v, k - 1, kind]`` is the weight of expert ``(k, kind)`` of view ``v``, relative
    to the view's leader (so in ``[exp(-SPREAD), 1]``, or ``ASLEEP``); ``detector[v]`` holds
    the view's tests (fields ``CUSUM`` .. ``START``, :data:`DETECTOR_FIELDS` in all);
    ``epoch[v]`` counts the view's alarms.
    """

    weight: np.ndarray    # float64 (views, K, 3)
    detector: np.ndarray  # float64 (views, DETECTOR_FIELDS)
    epoch: np.ndarray     # int32 (views,)


def new_mixer(views: int, max_context: int) -> Mixer:
    """Fresh weights: everything equal but the tie-breaking prior."""
    weight = np.empty((views, max_context, N_KINDS))
    weight[:] = (_TIE / _TIE.max()) * (1.0 - 1e-12 * np.arange(max_context))[:, None]
    weight[:, :, FRESH] = ASLEEP
    return Mixer(weight, np.zeros((views, DETECTOR_FIELDS)), np.zeros(views, np.int32))


def with_views(mixer: Mixer, views: int) -> Mixer:
    """``mixer`` extended with fresh state for new views."""
    have = len(mixer.epoch)
    if views <= have:
        return mixer
    extra = new_mixer(views - have, mixer.weight.shape[1])
    return Mixer(*(np.concatenate((a, b)) for a, b in zip(mixer, extra)))


def shifted_detector(detector: np.ndarray, shift: int) -> np.ndarray:
    """``detector`` with its clocks moved ``shift`` steps later (a library learned after
    another, on the merged clock)."""
    out = detector.copy()
    out[:, list(CLOCK_FIELDS)] += shift
    return out


def upgraded_detector(old: np.ndarray, clock: int) -> np.ndarray:
    """A detector of library format 2 in this layout. Format 2 had one test, ``(cusum,
    misses, trials)``, the first of :data:`DROPS`; it kept no clocks, so they are taken as
    ``clock`` (the library's): the next alarm counts fresh occurrences from loading on."""
    out = np.zeros((len(old), DETECTOR_FIELDS))
    out[:, CUSUM] = old[:, 0]
    out[:, MISSES], out[:, TRIALS] = old[:, 1], old[:, 2]
    out[:, list(CLOCK_FIELDS)] = clock
    return out


@helper
def select(w, v, cand, n):
    """The awake expert of largest weight among contexts ``1..n`` of view ``v``:
    ``(length, kind)``. ``cand[k, kind]`` is the expert's outcome, or -1 (asleep).

    A sleeping expert lends its weight to its shorter twins (same kind): when the leader's
    context is missing from the history (never seen, or longer than the history), its own
    kind at the longest context found speaks, as PPM backs off to a shorter context.
    Equal weights go to the longest context.
    """
    best_w, best_k, best_kind = -1.0, 0, 0
    lent_frequent, lent_recent, lent_fresh = 0.0, 0.0, 0.0  # no allocation in helpers
    for k in range(w.shape[1], 0, -1):
        for kind in range(N_KINDS):
            lent = lent_frequent if kind == FREQUENT else lent_recent if kind == RECENT else lent_fresh
            x = max(w[v, k - 1, kind], lent)
            if k <= n and cand[k, kind] >= 0:
                if x > best_w:
                    best_w, best_k, best_kind = x, k, kind
            elif kind == FREQUENT:
                lent_frequent = x
            elif kind == RECENT:
                lent_recent = x
            else:
                lent_fresh = x
    return best_k, best_kind


@helper
def update(w, v, cand, n, truth):
    """Hedge's sleeping-experts step, then the leader rescaled to 1 and the spread bound."""
    before = 0.0
    after = 0.0
    for k in range(1, n + 1):
        for kind in range(N_KINDS):
            if cand[k, kind] >= 0:
                before += w[v, k - 1, kind]
                if cand[k, kind] != truth:
                    w[v, k - 1, kind] *= _BETA
                after += w[v, k - 1, kind]
    if after <= 0.0:
        return
    ratio = before / after
    for k in range(1, n + 1):
        for kind in range(N_KINDS):
            if cand[k, kind] >= 0:
                w[v, k - 1, kind] *= ratio
    leader = 0.0
    for k in range(w.shape[1]):
        for kind in range(N_KINDS):
            leader = max(leader, w[v, k, kind])
    scale = 1.0 / leader
    for k in range(w.shape[1]):
        for kind in range(N_KINDS):
            x = w[v, k, kind] * scale
            w[v, k, kind] = _FLOOR if 0.0 < x < _FLOOR else x


@helper
def trusted_length(w, v, cand, n, epoch):
    """The context length of the frequency expert of largest weight, or 0: all-time counts
    before the first alarm, fresh counts after it (all-time counts are known stale then)."""
    kind = FREQUENT if epoch == 0 else FRESH
    best_w, out = -1.0, 0
    for k in range(1, n + 1):
        if cand[k, kind] >= 0 and w[v, k - 1, kind] >= best_w:
            best_w, out = w[v, k - 1, kind], k
    return out


@helper
def detect(w, det, v, hit, p_hit, clock):
    """Feed one prediction (at ``clock``) of the trusted frequency expert to view ``v``'s
    CUSUM tests.

    ``p_hit`` is the expert's own probability of being right (see the module docstring):
    the tests compare the misses with the misses expected context by context, so easy and
    hard contexts do not pass for a change. Returns whether a test raised an alarm (and if
    so, resets them all, writes the change point in ``START`` and starts the ``FRESH``
    experts from their frequency twins).
    """
    det[v, MISSES] += 0.0 if hit else 1.0
    det[v, TRIALS] += 1.0
    alarm = -1
    for i in range(N_TESTS):
        step = -np.log(_DROPS[i]) if hit else np.log((1.0 - p_hit / _DROPS[i]) / (1.0 - p_hit))
        x = max(0.0, det[v, CUSUM + i] + step)
        det[v, CUSUM + i] = x
        if x == 0.0:
            det[v, CALM + i] = clock + 1.0  # a change, if any, came after this step
        if x >= _THRESHOLD and (alarm < 0 or x > det[v, CUSUM + alarm]):
            alarm = i
    if alarm < 0:
        return False
    det[v, START] = det[v, CALM + alarm]
    for i in range(N_TESTS):
        det[v, CUSUM + i] = 0.0
        det[v, CALM + i] = clock + 1.0
    det[v, MISSES] = 0.0
    det[v, TRIALS] = 0.0
    for k in range(w.shape[1]):
        w[v, k, FRESH] = max(w[v, k, FREQUENT], w[v, k, FRESH]) * (_TIE[FRESH] / _TIE[FREQUENT])
    return True
