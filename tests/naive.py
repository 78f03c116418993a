"""Plain-Python reference models of the core, for property tests."""

from __future__ import annotations

from collections import defaultdict


class NaiveLibrary:
    """S-learning's rule on a dict of token tuples: pattern -> [count, last_seen]."""

    def __init__(self, max_length: int) -> None:
        self.max_length = max_length
        self.patterns: dict[tuple[int, ...], list[int]] = {}
        self.clock = 0

    def learn(self, tokens: list[int]) -> None:
        if not tokens:
            return
        cur, cur_len = (tokens[0],), 0
        for step in range(1, (len(tokens) - 1) // 2 + 1):
            a, o = tokens[2 * step - 1], tokens[2 * step]
            while True:
                ext = cur + (a, o)
                if cur_len < self.max_length and ext in self.patterns:
                    cur, cur_len = ext, cur_len + 1
                    break
                if cur_len > 0:
                    self.patterns[cur][0] += 1
                    self.patterns[cur][1] = self.clock
                if cur_len < self.max_length:
                    self.patterns[ext] = [1, self.clock]
                    cur, cur_len = (o,), 0
                    break
                cur, cur_len = (cur[-1],), 0
            self.clock += 1
        if cur_len > 0:
            self.patterns[cur][0] += 1
            self.patterns[cur][1] = self.clock - 1


def naive_context_stats(patterns: dict[tuple[int, ...], list[int]], context: tuple[int, ...]):
    """outcome -> [weight, last_seen] over every occurrence of ``context`` (ending with an
    action: ``O A ... O A`` or ``A O ... O A``) inside a pattern and followed by an outcome."""
    stats: dict[int, list[int]] = defaultdict(lambda: [0, -1])
    n = len(context)
    for pattern, (count, last_seen) in patterns.items():
        for start in range(n % 2, len(pattern) - n, 2):
            if pattern[start:start + n] == context:
                entry = stats[pattern[start + n]]
                entry[0] += count
                entry[1] = max(entry[1], last_seen)
    return dict(stats)


def view_streams(steps, view_of, has_actions):
    """Per step, the tokens each view's stream gains, as ``(kind, symbols)`` tuples.

    ``steps`` are ``(actions, observations)`` symbol tuples; ``view_of`` maps observation
    symbols to views. Yields ``(view, context so far, outcome or None)`` per view that
    reported, after the step's action was appended (the spec of :mod:`slearn.core.views`).
    """
    streams: dict[int, list] = defaultdict(list)
    held: dict[int, tuple] = {}
    views = sorted(set(view_of.values()))
    for s, (actions, observations) in enumerate(steps):
        push_action = has_actions and (s > 0 or bool(actions))
        if push_action:
            for v in views:
                streams[v].append(("A", tuple(actions)))
        reported = {}
        for symbol in observations:
            if symbol in view_of:
                reported.setdefault(view_of[symbol], []).append(symbol)
        events = []
        for v in views:
            if v in reported:
                outcome = ("O", tuple(reported[v]))
                events.append((v, list(streams[v]), outcome))
                streams[v].append(outcome)
                held[v] = outcome
            elif push_action:
                streams[v].append(held.get(v, ("O", ())))
        yield events


class NaiveOccurrences:
    """Every occurrence of every context, on a dict: (view, context, outcome) -> [count, last_seen]."""

    def __init__(self, max_context: int, view_of: dict[int, int], has_actions: bool) -> None:
        self.max_context = max_context
        self.view_of = view_of
        self.has_actions = has_actions
        self.patterns: dict[tuple, list[int]] = {}
        self.clock = 0

    def learn(self, steps) -> None:
        for events in view_streams(steps, self.view_of, self.has_actions):
            for view, stream, outcome in events:
                for k in range(1, min(len(stream), self.max_context) + 1):
                    key = (view, tuple(stream[-k:]), outcome)
                    entry = self.patterns.setdefault(key, [0, 0])
                    entry[0] += 1
                    entry[1] = self.clock
            self.clock += 1
