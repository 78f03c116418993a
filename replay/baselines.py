"""The baselines a reviewer asks for, run on the same view streams as the library.

* ``frequency``: the most frequent next observation given the view's last observation
  and the action just issued (a first-order transition table).
* ``markov``: a variable-order Markov model whose contexts reach as far back as the
  library's (``max_length`` steps) and back off to shorter ones until one has been seen;
  within a context the most frequent outcome wins (ties to the most recent). It counts
  every occurrence, as the library does: the library's lift over it is what its scoring
  adds to the same counts.
* ``persistence``: the view's last observation again ("the value stays the same").

The counts are those of a :class:`~slearn.core.library.PatternLibrary` of the library's shape
that shares its tokens, so predictions compare with the library's one for one. With no
context at all (nothing seen yet) ``frequency`` and ``markov`` abstain.
"""

from __future__ import annotations

from slearn.core.library import PatternLibrary
from slearn.core.literal import LiteralLibrary
from slearn.core.online import Reports
from slearn.core.tokens import ACTION, OBSERVATION
from slearn.core.views import StepCodes

FREQUENCY = "frequency"
MARKOV = "markov"
PERSISTENCE = "persistence"
NAMES = (FREQUENCY, MARKOV, PERSISTENCE)


class Baselines:
    """The three baselines over one count table shaped like ``library``'s."""

    def __init__(self, library: PatternLibrary | LiteralLibrary) -> None:
        literal = isinstance(library, LiteralLibrary)
        self.source = library
        self.counts = PatternLibrary(
            library.max_length, None, None if literal else library.vocabulary,
            True if literal else library._has_actions)
        self.counts.tokens = library.tokens
        self.counts.empty_action = library.tokens.intern(ACTION, ())
        self.counts.empty_observation = library.tokens.intern(OBSERVATION, ())
        self.steps_learned = 0

    @property
    def max_length(self) -> int:
        return self.counts.max_length

    def learn(self, codes: StepCodes) -> None:
        """Count every observation of one encoded episode."""
        self.run(codes, learn=True)

    def run(self, codes: StepCodes, learn: bool) -> Reports:
        """The baselines' predictions for every report of an encoded episode (``markov``,
        ``frequency``, ``persistence`` of the returned reports), counting each observation
        after predicting it if ``learn``."""
        if learn:
            self.steps_learned += len(codes)
        if self.counts._has_actions is None:  # decided by the library's first episode
            self.counts._has_actions = self.source.has_actions
        return self.counts.run(codes, learn=learn, record=False, baselines=True)
