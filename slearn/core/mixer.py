"""How the contexts of one prediction are weighed: exponential weights over experts.

For one view (one observation channel), the candidates of a prediction are the
contexts of length ``1..K`` found in the tree. Each context offers three *experts*:

* ``FREQUENT``: its outcome seen most often (all time);
* ``RECENT``: its outcome seen last;
* ``FRESH``: its outcome seen most often since the view's current epoch began.

An expert is ``(context length, kind)``. An expert whose context is missing (never seen,
or longer than the history) backs off as PPM does: it says what its longest shorter twin
(same kind) found says; an expert with no twin found sleeps. The awake expert of largest
weight speaks (Hedge with sleeping experts, Freund et al. 1997): after the outcome, every
awake expert that was wrong loses ``ETA`` of log-weight (its weight is multiplied by
``exp(-ETA)``), then the awake experts' total is restored, so sleeping experts neither
gain nor lose. A backed-off expert answers for what it said: when a long context's expert
of high weight was missing and its short twin spoke for it with that weight, both lose
when it was wrong. (Until 2026-12-04 a missing context's expert slept and lent its
weight to its twin without answering for it: after a switch back, a short fresh expert
speaking with a sleeping long one's weight went on through runs of 20 misses. Measured on
``bench_variants.py``: the thousand after that switch back 94.2 to 96.8 %, steady state
within 0.2 everywhere; the PR2 laser tilt at ``--split 0.6`` 487 to 495 of 527, as the
Markov baseline.)
Weights stay within ``SPREAD`` of the leader, so an expert that was poor for a long
time can take over after a few dozen mistakes of the leader: the mixture tracks the best
expert when it changes (a switch of dynamics), as fixed-share does.

The experts learn: a long context's counts are thin at first, so its early mistakes say
little about it once its counts have filled in. So each view counts its *rounds*
(predictions with an awake expert), and each time they reach a power of two every
log-weight is halved (the weight's square root: the ranking stays, the distances halve):
a mistake made before the view had half its present experience counts half, one made
before a quarter counts a quarter. This is the doubling trick of online learning
(restart at rounds ``2^j``, Cesa-Bianchi & Lugosi 2006) made soft, and it has no constant.
On the PR2 log's laser tilt joint, learned from 927 steps, the long contexts that lost the
first hundreds of predictions and won the last ones lead after the last doubling (frozen
held-out 372 of 397, as the Markov baseline, instead of 370).

Epochs. Counts accumulated before a change of dynamics mislead frequency forever. A
Bernoulli CUSUM test (Page 1954) watches the most trusted frequency expert: each of its
predictions has its own expected miss rate ``q0`` (one minus the probability PPM's method C
gives its outcome in its context: the outcome's count over the context's total plus one
escape count per distinct outcome), and the test accumulates the
log-likelihood ratio of ``q1 = (1 + q0) / 2`` against it, so a miss where the context is
nearly certain weighs much, a miss where it is a coin toss little. It raises an alarm past
``ln(1 / FALSE_ALARM)`` (the false-alarm rate per prediction is at most ``FALSE_ALARM``
when the shares are calibrated).

Calibration. PPM's shares are not calibrated where contexts are seen a few times: a
context seen once gives its outcome 1/2, whether the stream is a clock or a die of a
thousand faces, and the test took every miss of a once-seen context of a random stream
as evidence of a change (hundreds of false alarms in 200,000 symbols). So the share is
corrected by what happened to shares like it, as PPMZ's secondary escape estimation
(Bloom 1998) and paq's adaptive probability maps correct a model's probabilities: each
view counts, per *cell* (the octave of the context's count, times the octave of the
odds ``1 / q0``), how often the trusted expert was right, over all time, and the test
uses ``(hits + e * p) / (trials + e)`` with ``e = n + PRIOR``: the cell's record and PPM's
own share ``p``, each weighed by its evidence (the cell's trials; the context's count
``n``, plus ``PRIOR`` pseudo-observations so that an empty cell keeps PPM's share). A
context seen once weighs three predictions, so the cells of a random stream correct it
after a few dozen; a context seen a thousand times keeps its share until its cell has
seen thousands of predictions, so the misses just after a change, which land in the
cell too, do not teach the test to expect them. An alarm opens a new epoch:
fresh counts restart from zero (:mod:`slearn.core.context_tree`), dated from the change the
test estimates, not from the alarm: the reports since its statistic was last zero (Page's
estimate of where the change began) count again as fresh (:class:`slearn.core.online.Past`),
as an empty library started at the change would have counted them (on ``reversal+error``
the thousand trials after the switch went from 64.9 to 65.7 %, an empty library started at
the switch scores 66.0; ``bench/bench_variants.py``). The alarm declares the counts
before it stale, not what a context length is worth: at each length the ``FRESH`` expert
takes the length's best weight and speaks at once, and the ``FREQUENT`` expert of the
length goes just below it (the ``RECENT`` one keeps its record, which is not what the test
watched). So the all-time counts take over again after the first prediction where they
are right and the fresh ones wrong, and a regime that comes back finds its all-time
experts at the front, not wherever they fell while the regime in between was fresh. A
false alarm costs the predictions until the fresh counts' first loss to the all-time
ones (the public sequence sets of ``bench/bench_sequences.py``, where alarms are false or
weak, did not move).
(Until 2026-12-07 the ``FRESH`` experts started just below their ``FREQUENT`` twins and
spoke after the first prediction where the all-time counts were wrong and the fresh ones
right. Measured on ``bench/bench_variants.py``, seeds 0-19: the thousand after the
switches back 96.6 to 99.5 % (``reversal``) and 96.3 to 99.3 (``scramble``), after
``reversal @2000`` 92.9 to 93.0, ``reversal+error`` 66.4 to 66.5, ``reversal+delay`` 37.2 to
37.4; steady states, the six conditions' windows, the sequence sets and the PR2 log
unchanged. Lifting the ``RECENT`` experts too cost ``reversal+delay`` a point, 37.7 to
36.7 on seeds 0-4; leaving ``FREQUENT`` where it was when it was already lower kept the
switches back at 96.7 and 96.6.)

Ties go to ``FREQUENT``, then ``RECENT``, then ``FRESH``: experts that never disagreed
where it mattered leave the prediction to the all-time counts (a context's latest outcome
that followed it once must not outvote hundreds before it: a stream that drifted A, B, C
predicted a held-out run of A's as B's while ties went to ``RECENT``). Within the
leader's kind, the longest context whose expert is less than one mistake (``ETA`` of
log-weight) behind the leader speaks: Hedge's weights do not tell such experts apart (a
mistake made before the last doubling of the rounds counts half), and the longer context
conditions on more, as a variable-order model takes its longest match. Experts whose
weights differ by the prior only (within ``SAME``: they never disagreed) are tied, and
with no evidence between them the simplest explanation speaks, the shorter context (on a
deterministic stream every context agrees, and the frozen look-ups stop at the shortest).
(Until 2026-12-06 the leader spoke however close the next was: on the PR2 log's laser
tilt joint, learned from its first 40 % or 50 %, the 6-step frequency expert trailed the
1-step one by half a mistake, and the held-out part scored 734 of 794 and 607 of 660
against the Markov baseline's 745 and 618; now 745 and 618. ``bench_sequences.py`` did
not move, ``bench_variants.py`` by at most 0.1, its switches not at all. Without the tie
rule the first thousand trials from an empty library rose by 0.1, three switches fell by
0.1, and ``predict_batch`` on pointer ``simple`` fell from 5.0 to 2.1 M queries/s, every
query looking up its longest context.) No constant is tuned to a data set:
``ETA`` is Hedge's rate for tens of experts over ~10^4 predictions, ``SPREAD`` bounds the
catch-up to ``SPREAD / ETA`` net mistakes, ``FALSE_ALARM`` is a rate and ``PRIOR`` the
evidence (two predictions) PPM's share has where a context was never seen; the measured
tables in ``bench/`` are flat over a factor of two in each.

Persistence. Every expert reads categorical counts, so where the contexts that carry the
present are missing (a reading never met with this command since a change, say) the
answer comes from a short context that cannot tell where the reading is, and is wrong
almost always, while a physical reading often simply stays where it was. So each view
has one more specialist per context length ``k`` (Freund et al. 1997): *persistence*,
the view's last reading again, awake in the rounds whose answer came from a context of
length ``k``. It and that answer are two experts of their own Hedge: ``persist[v, k -
1]`` is its weight over the answer's, multiplied by ``exp(ETA)`` when it was right and
the answer wrong and by ``exp(-ETA)`` the other way, within ``exp(+-SPREAD)``, halved in
log at the view's powers of two of rounds as the weights are; it speaks when above 1 (a
tie leaves the answer), and its ranking is the two experts' mixture
(:func:`slearn.core.online.record_persistence`). So a stream whose readings do not
persist keeps its answers (the record only falls), and one where they do keeps
persistence for the lengths where it wins: on the delayed pointer the answers of 1-token
contexts (a command, with no position) were right 29 % of the time and the last reading
39 %. Measured on ``bench/bench_variants.py``, seeds 0-19: the thousand after the
``reversal+error`` switch 65.6 to 66.4 % (the first thousand 66.1 to 66.5),
``scramble+error`` 65.3 to 66.1, ``reversal+delay`` 35.4 to 37.2; steady states within
0.2, ``delay 0.7`` 58.1 to 58.3; the sequence sets, the arm and the PR2 log unchanged.
Resetting the specialists at an alarm (their record compares answers from counts the
alarm declared stale) cost 0.1-0.3 on those three switches; not done.
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
_THRESHOLD = float(np.log(1.0 / FALSE_ALARM))
BETA = float(np.exp(-ETA))  # a wrong expert's weight factor: one mistake
SAME = 1e-10  # weights closer than this share a record: they differ by the prior (_TIE) only
_FLOOR = float(np.exp(-SPREAD))
_TIE = np.array([1.0, 1.0 - 2e-9, 1.0 - 4e-9])  # prior weight per kind: FREQUENT, then RECENT, win ties
_BELOW = float(_TIE[FRESH] / _TIE[FREQUENT])  # after an alarm, the all-time counts just below the fresh ones
ASLEEP = 0.0  # the weight of FRESH experts before the first epoch
CUSUM, MISSES, TRIALS = 0, 1, 2
OCTAVES = 16  # calibration cells per axis: counts 1 to 2^15 and more, odds 1 to 2^15 and more
CELLS = OCTAVES * OCTAVES
HITS, SEEN = 0, 1
PRIOR = 2.0  # PPM's share weighs as the context's count plus this many predictions


class Mixer(NamedTuple):
    """Expert weights, persistence specialists and change detectors of all views.

    ``weight[v, k - 1, kind]`` is the weight of expert ``(k, kind)`` of view ``v``, relative
    to the view's leader (so in ``[exp(-SPREAD), 1]``, or ``ASLEEP``); ``detector[v]`` holds
    ``(cusum, misses, trials)`` of the view's test since its epoch began; ``epoch[v]``
    counts the view's alarms; ``calibration[v, cell]`` holds ``(hits, trials)`` of the
    test's predictions in each :func:`calibration_cell`, over all time; ``rounds[v]``
    counts the view's weight updates (the halving of log-weights at each power of two);
    ``persist[v, k - 1]`` is the weight of the view's persistence specialist over the
    answer it would replace in rounds answered by a context of length ``k``.
    """

    weight: np.ndarray       # float64 (views, K, 3)
    detector: np.ndarray     # float64 (views, 3)
    epoch: np.ndarray        # int32 (views,)
    calibration: np.ndarray  # int64 (views, CELLS, 2)
    rounds: np.ndarray       # int64 (views,)
    persist: np.ndarray      # float64 (views, K)


def new_mixer(views: int, max_context: int) -> Mixer:
    """Fresh weights: everything equal but the tie-breaking prior."""
    weight = np.empty((views, max_context, N_KINDS))
    weight[:] = (_TIE / _TIE.max()) * (1.0 - 1e-12 * np.arange(max_context))[:, None]
    weight[:, :, FRESH] = ASLEEP
    return Mixer(weight, np.zeros((views, 3)), np.zeros(views, np.int32),
                 np.zeros((views, CELLS, 2), np.int64), np.zeros(views, np.int64),
                 np.ones((views, max_context)))


def with_views(mixer: Mixer, views: int) -> Mixer:
    """``mixer`` extended with fresh state for new views."""
    have = len(mixer.epoch)
    if views <= have:
        return mixer
    extra = new_mixer(views - have, mixer.weight.shape[1])
    return Mixer(*(np.concatenate((a, b)) for a, b in zip(mixer, extra)))


@helper
def select(w, v, cand, n):
    """The expert that speaks among contexts ``1..n`` of view ``v``: ``(length, kind,
    weight)``, ``weight`` the leader's (the largest, with what it was lent).
    ``cand[k, kind]`` is the expert's outcome, or -1 (asleep).

    The leader is the awake expert of largest weight. A sleeping expert lends its weight
    to its shorter twins (same kind): when the leader's context is missing from the
    history (never seen, or longer than the history), its own kind at the longest context
    found speaks, as PPM backs off to a shorter context. The longest context found whose
    own expert of the leader's kind is :func:`near` it (less than one mistake behind, not
    tied) speaks for it: the weights do not tell such experts apart, and the longer
    context conditions on more, as a variable-order model's longest match does. Experts
    tied with the leader never disagreed with it: the shorter context speaks.
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
    for k in range(min(n, w.shape[1]), best_k, -1):  # the longest less than a mistake behind
        if cand[k, best_kind] >= 0 and near(w[v, k - 1, best_kind], best_w):
            return k, best_kind, best_w
    return best_k, best_kind, best_w


@helper
def near(x, lead):
    """Whether an expert of weight ``x`` is less than one mistake behind a leader of weight
    ``lead`` without being tied with it (``x`` within ``SAME`` of ``lead``: the two never
    disagreed, and then the shorter context speaks)."""
    return lead * BETA < x < lead * (1.0 - SAME)


@helper
def heaviest_beyond(w, beyond, lead):
    """For frozen weights, per view ``v`` (``K`` its longest context): ``beyond[v, k]``,
    the largest weight of its experts of contexts longer than ``k`` (-1 past the longest);
    ``beyond[v, K + 1 + k]``, the same among those not tied with the view's largest weight
    (within ``SAME`` of it); and ``lead[v]``, the longest context with an expert of the
    largest weight or :func:`near` it. When :func:`select` chose from contexts ``1..n``
    only (the longer ones taken as asleep) a leader that outweighs ``beyond[v, n]`` and,
    less one mistake, ``beyond[v, K + 1 + n]``, the longer contexts cannot change its
    choice (their experts weigh less, are tied with it or a mistake behind it, and what
    they lent did not decide), so they need not be looked up."""
    K = w.shape[1]
    for v in range(w.shape[0]):
        top = 0.0
        for k in range(K):
            for kind in range(N_KINDS):
                top = max(top, w[v, k, kind])
        beyond[v, K] = -1.0
        beyond[v, 2 * K + 1] = -1.0
        lead[v] = 0
        for k in range(K, 0, -1):
            heaviest, untied = beyond[v, k], beyond[v, K + 1 + k]
            for kind in range(N_KINDS):
                x = w[v, k - 1, kind]
                heaviest = max(heaviest, x)
                if x < top * (1.0 - SAME):
                    untied = max(untied, x)
                if lead[v] == 0 and (x == top or near(x, top)):
                    lead[v] = k
            beyond[v, k - 1], beyond[v, K + k] = heaviest, untied
        lead[v] = max(lead[v], 1)


@helper
def _first_awake(cand, n, kind, K):
    """The shortest context length whose expert of ``kind`` found its context (``K + 1``
    if none did). Every longer expert is awake too: one whose context is missing says
    what its longest shorter twin says."""
    for k in range(1, min(n, K) + 1):
        if cand[k, kind] >= 0:
            return k
    return K + 1


@helper
def halving(t):
    """Whether round ``t`` of a view halves its log-weights: a power of two past the first."""
    return t > 1 and t & (t - 1) == 0


@helper
def update(w, rounds, v, cand, n, truth):
    """Hedge's sleeping-experts step (a missing context's expert says what its longest
    shorter twin found says), then the leader rescaled to 1 and the spread bound;
    a round that reaches a power of two first halves every log-weight of the view."""
    if n == 0:
        return
    rounds[v] += 1
    if halving(rounds[v]):
        for k in range(w.shape[1]):
            for kind in range(N_KINDS):
                w[v, k, kind] = np.sqrt(w[v, k, kind])
    before = 0.0
    after = 0.0
    K = w.shape[1]
    for kind in range(N_KINDS):
        said = -1
        for k in range(_first_awake(cand, n, kind, K), K + 1):
            if k <= n and cand[k, kind] >= 0:
                said = cand[k, kind]
            before += w[v, k - 1, kind]
            if said != truth:
                w[v, k - 1, kind] *= BETA
            after += w[v, k - 1, kind]
    if after <= 0.0:
        return
    ratio = before / after
    for kind in range(N_KINDS):
        for k in range(_first_awake(cand, n, kind, K), K + 1):
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
def persists(persist, v, length, last):
    """Whether view ``v``'s persistence specialist speaks instead of an answer from a
    context of ``length``: the view has a last reading ``last`` and the specialist
    outweighs that answer."""
    return last >= 0 and length > 0 and persist[v, length - 1] > 1.0


@helper
def update_persist(persist, rounds, v, length, said, last, truth):
    """After each :func:`update` that counted a round (``rounds[v]``): the log-weights
    halved when the round is a power of two, then the two-expert Hedge of the answer
    ``said`` from a context of ``length`` and the last reading ``last`` (none: -1)."""
    if halving(rounds[v]):
        for k in range(persist.shape[1]):
            persist[v, k] = np.sqrt(persist[v, k])
    if last < 0 or length <= 0:
        return
    x = persist[v, length - 1]
    if last == truth and said != truth:
        x = min(x / BETA, 1.0 / _FLOOR)
    elif last != truth and said == truth:
        x = max(x * BETA, _FLOOR)
    persist[v, length - 1] = x


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
def calibration_cell(c, total, distinct):
    """The calibration cell of a share ``c / (total + distinct)`` by PPM's method C (an
    outcome seen ``c`` times after a context seen ``total`` times, with ``distinct``
    outcomes): the octave of ``total``, times the octave of the odds against a miss,
    ``(total + distinct) / (total + distinct - c)``. In integers, so any implementation
    agrees on the cell."""
    count_octave = 0
    while count_octave < OCTAVES - 1 and total >> (count_octave + 1) > 0:
        count_octave += 1
    whole = np.int64(total) + distinct
    miss = whole - c
    odds_octave = 0
    while odds_octave < OCTAVES - 1 and miss << (odds_octave + 1) <= whole:
        odds_octave += 1
    return count_octave * OCTAVES + odds_octave


@helper
def detect(w, det, cal, v, hit, c, total, distinct):
    """Feed one prediction of the trusted frequency expert to view ``v``'s CUSUM test: its
    outcome was seen ``c`` times after a context seen ``total`` times with ``distinct``
    outcomes (fresh counts), and it was right or not (``hit``).

    The expected miss rate is one minus the share PPM's method C gives the outcome,
    calibrated by the view's cell of such shares (see the module docstring): the test
    compares the misses with the misses expected context by context, so easy and hard
    contexts do not pass for a change. Returns whether the test raised an alarm (and if
    so, resets it and starts each length's ``FRESH`` expert at the length's best weight,
    its ``FREQUENT`` one just below).
    """
    if total <= 0:
        return False
    cell = calibration_cell(c, total, distinct)
    share = c / (total + distinct)
    evidence = PRIOR + total
    p_hit = (cal[v, cell, HITS] + evidence * share) / (cal[v, cell, SEEN] + evidence)
    cal[v, cell, HITS] += 1 if hit else 0
    cal[v, cell, SEEN] += 1
    q0 = 1.0 - p_hit
    q1 = 0.5 * (1.0 + q0)
    step = np.log((1.0 - q1) / (1.0 - q0)) if hit else np.log(q1 / q0)
    det[v, CUSUM] = max(0.0, det[v, CUSUM] + step)
    det[v, MISSES] += 0.0 if hit else 1.0
    det[v, TRIALS] += 1.0
    if det[v, CUSUM] < _THRESHOLD:
        return False
    det[v, CUSUM] = 0.0
    det[v, MISSES] = 0.0
    det[v, TRIALS] = 0.0
    for k in range(w.shape[1]):
        best = max(w[v, k, FREQUENT], w[v, k, RECENT], w[v, k, FRESH])
        w[v, k, FRESH] = best
        w[v, k, FREQUENT] = best * _BELOW
    return True
