"""Planning: routes read off the library, probabilities, backoff, unknowns and curiosity."""

import numpy as np
import pytest
from test_literal import L, R, pointer_episode

from slearn.control.planner import Planner, PlannerSettings, distribution
from slearn.core.library import PatternLibrary
from slearn.core.stream import Episode
from slearn.core.tokens import ACTION, OBSERVATION
from slearn.recorders.pointer import PointerConfig, simulate

POS = 10  # position k is symbol k + 10 (see test_library.pointer_episode)
POINTER_L, POINTER_R = 0, 1  # in pointer_vocabulary, label k is symbol k + 1
CAUTIOUS = PlannerSettings(optimism=0.0)  # untried actions are not worth the goal (no exploration)


def steps(text: str):
    return pointer_episode(text).steps()


def learned(*texts: str, max_length: int = 5, times: int = 1) -> PatternLibrary:
    library = PatternLibrary(max_length)
    for _ in range(times):
        for text in texts:
            library.learn(pointer_episode(text))
    return library


@pytest.fixture(scope="module")
def simple_library() -> PatternLibrary:
    library = PatternLibrary()
    library.learn(simulate(PointerConfig("simple", 10_000, 0)).to_episode())
    return library


@pytest.fixture(scope="module")
def hardstop_library() -> PatternLibrary:
    library = PatternLibrary()
    library.learn(simulate(PointerConfig("hardstop", 10_000, 0)).to_episode())
    return library


def test_shortest_route_on_the_learned_pointer(simple_library):
    planner = Planner(simple_library)
    plan = planner.plan([((), (4 + 1,))], 11 + 1)
    assert plan.actions == ((POINTER_R,),) * 7
    assert plan.observations == tuple((k + 1,) for k in range(5, 12))
    assert 0.8 < plan.probability <= 1.0 and not plan.explore
    # across the 36/1 boundary the other way round is shorter
    plan = planner.plan([((), (3 + 1,)), ((POINTER_L,), (2 + 1,))], 35 + 1)
    assert plan.actions == ((POINTER_L,),) * 3
    assert plan.observations == ((1 + 1,), (36 + 1,), (35 + 1,))


def test_hard_stop_forces_the_long_way(hardstop_library):
    plan = Planner(hardstop_library).plan([((), (35 + 1,))], 2 + 1)
    assert plan.actions == ((POINTER_L,),) * 33
    assert plan.probability > 0.5


def test_goal_already_observed_and_goal_sets(simple_library):
    planner = Planner(simple_library)
    plan = planner.plan([((), (7 + 1,))], {3 + 1, 7 + 1})
    assert plan.reached and plan.action is None and plan.probability == 1.0
    plan = planner.plan([((), (7 + 1,))], {3 + 1, 9 + 1, 30 + 1})
    assert plan.actions == ((POINTER_R,),) * 2  # the nearest of the goals


def test_more_probable_action_wins_and_fewer_steps_win():
    library = learned("1 R 2", "1 L 1", "1 L 2", max_length=1, times=5)
    plan = Planner(library).plan(steps("1"), 2 + POS)
    assert plan.action == (R,)
    # R reaches 3 in two sure steps, L in one step half of the time: the search weighs both
    library = learned("1 R 2 R 3", "1 L 3", "1 L 1", max_length=2, times=5)
    planner = Planner(library, settings=PlannerSettings(discount=0.5))
    assert planner.plan(steps("1"), 3 + POS).action == (L,)
    planner = Planner(library, settings=PlannerSettings(discount=0.99))
    assert planner.plan(steps("1"), 3 + POS).action == (R,)


def test_longer_context_changes_the_outlook():
    # after 1 R 2, R goes on to 3; after 3 L 2, R jumps to 4
    library = learned("1 R 2 R 3", "3 L 2 R 4", max_length=2, times=4)
    planner = Planner(library, settings=CAUTIOUS)
    ahead = planner.plan(steps("1 R 2"), 3 + POS)
    back = planner.plan(steps("3 L 2"), 3 + POS)
    assert ahead.action == (R,) and ahead.probability > 0.6
    assert back.probability < ahead.probability
    blind = Planner(library, settings=PlannerSettings(order=0, optimism=0.0)).plan(steps("3 L 2"), 3 + POS)
    assert blind.probability > back.probability  # order 0 mixes both contexts


def test_distribution_sums_to_one_with_the_unknown_share():
    library = PatternLibrary()
    library.learn(simulate(PointerConfig("error", 2_000, 3)).to_episode())
    library.prepare()
    tree, root = library.tree, int(library.streams.root[0])
    table = library.tokens
    outcomes, probs, work = (np.zeros(len(table), np.int32), np.zeros(len(table)), np.zeros(len(table)))
    cand = np.zeros(3, np.int32)
    checked = 0
    for p in range(2, 36):
        for a in (POINTER_L, POINTER_R):
            tokens = np.array([table.find(OBSERVATION, (p,)), table.find(ACTION, (a,)),
                               table.find(OBSERVATION, (p + 1,))], np.int32)
            for levels in (1, 2):
                k, unknown = distribution(tree, root, tokens, 2, table.find(ACTION, (POINTER_R,)),
                                          levels, 1.0, 0.5, library.clock, 0.001, 0, 1.0, cand, outcomes,
                                          probs, work)
                assert k >= 1 and 0.0 < unknown < 1.0
                assert probs[:k].sum() + unknown == pytest.approx(1.0)
                checked += 1
    assert checked == 34 * 2 * 2


def test_unseen_observation_or_goal_explores_the_least_tried_action():
    library = learned("3 L 2", "3 L 4", "3 R 5", max_length=1)
    planner = Planner(library, settings=CAUTIOUS)
    plan = planner.plan(steps("3"), 9 + POS)  # 9 was never observed: no route
    assert plan.explore and plan.action == (R,) and plan.probability == 0.0
    library.learn(pointer_episode("3 R 5"))
    library.learn(pointer_episode("3 R 5"))
    assert planner.plan(steps("3"), 9 + POS).action == (L,)  # now L is the less tried
    plan = planner.plan(steps("8"), 3 + POS)  # 8 itself was never observed
    assert plan.explore and plan.action in ((L,), (R,))


def test_untried_action_is_unknown_and_worth_trying():
    library = learned("1 R 2", max_length=1, times=3)
    planner = Planner(library, actions=[(L,), (R,)], settings=CAUTIOUS)
    assert planner.actions == [(L,), (R,)]
    plan = planner.plan(steps("1"), 2 + POS)
    assert plan.action == (R,) and not plan.explore
    # no route to 5: curiosity picks L, never tried from 1
    assert planner.plan(steps("1"), 5 + POS).action == (L,)


def test_replanning_with_online_learning_follows_a_changed_world():
    library = learned("1 R 2 L 1 R 2 L 1 R 2 L 1 R 2 L 1", max_length=3, times=5)
    planner = Planner(library, settings=CAUTIOUS)
    before = planner.plan(steps("2 L 1"), 2 + POS)
    assert before.actions == ((R,),) and before.probability > 0.9
    for _ in range(20):  # the world changed: from 1, R now stays at 1
        library.learn(pointer_episode("2 L 1 R 1"))
    after = planner.plan(steps("2 L 1"), 2 + POS)
    assert after.observations[0] == (1 + POS,)  # the library now expects R to stay at 1
    assert after.value < before.value - 0.05  # so the route is worth less


def test_settings_are_checked():
    with pytest.raises(ValueError):
        PlannerSettings(discount=0.0)
    with pytest.raises(ValueError):
        PlannerSettings(order=-1)
    with pytest.raises(ValueError):
        Planner(PatternLibrary(), actions=[])
    with pytest.raises(ValueError):
        Planner(learned("1 R 2")).plan([], 2 + POS)


def test_a_bounded_search_loses_mass_but_still_plans(simple_library):
    planner = Planner(simple_library, settings=PlannerSettings(max_states=8))
    plan = planner.plan([((), (4 + 1,))], 11 + 1)
    assert plan.explore  # the goal lies beyond the states searched
    plan = planner.plan([((), (4 + 1,))], 6 + 1)
    assert plan.actions[0] == (POINTER_R,) and not plan.explore


def test_half_life_lets_recent_outcomes_outweigh_old_ones():
    library = learned("1 R 2", max_length=1, times=10)
    library.learn(pointer_episode("5 " + " ".join(["L 5"] * 200)))  # time passes elsewhere
    library.learn(pointer_episode("1 R 3 L 1 R 3 L 1 R 3"))
    steady = Planner(library, settings=PlannerSettings(stale=1e9, optimism=0.0)).plan(steps("1"), 3 + POS)
    fading = Planner(library, settings=PlannerSettings(half_life=20, stale=1e9, optimism=0.0)).plan(steps("1"), 3 + POS)
    assert steady.probability < 0.5 < fading.probability


def test_goal_mask_copes_with_empty_observation_tokens():
    library = PatternLibrary()
    for _ in range(3):  # a step that observed nothing
        library.learn(Episode.from_steps([((), (2 + POS,)), ((R,), (3 + POS,)), ((R,), ())]))
    assert library.tokens.find(OBSERVATION, ()) >= 0
    plan = Planner(library).plan([((), (2 + POS,))], 3 + POS)
    assert plan.action == (R,)
