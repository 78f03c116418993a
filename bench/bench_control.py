"""Goal-seeking control: slearn next to honest peers, on the pointer and on Gymnasium (issue 16).

Every agent learns from the same exploration and gets the same goals, each in its own copy
of the environment (same seed): slearn (pattern library + planner), a count model with
value iteration (optimistic for untried actions, resets a pair the world contradicts),
goal-conditioned Q-learning (every transition replayed for every goal), and Q-learning
trained for one goal (the paper's argument, not a fair peer). Prints:

- pointer, six conditions x seeds: goals reached overall, in the block right after the
  switch (reversal/scramble), within 1.05x / 2x the shortest path, per agent;
- the 72-bin hard-stop pointer (exploration leaves the far end unvisited);
- FrozenLake 4x4 / 8x8 (deterministic), CliffWalking: reached and within 1.05x;
- slippery FrozenLake 8x8 against value iteration on the true model (``env.unwrapped.P``);
- Taxi: passenger-delivered states (any of the four), passenger after passenger.

Run: ``python bench/bench_control.py [--goals 300] [--seeds 3] [--only pointer|gym]``.
"""

from __future__ import annotations

import argparse
import time

from slearn.control.closed_loop import AGENTS, ControlConfig, run_control

CONDITIONS = ("simple", "hardstop", "error", "delay", "reversal", "scramble")
NAMES = {"slearn": "slearn", "count-model": "count model", "goal-q": "goal-cond. Q",
         "q-one-goal": "Q one goal", "true-model": "true-model VI"}


def _cell(agent) -> str:
    s = agent.summary
    after = [b for b in agent.blocks if b.after_switch]
    first = f" ({100 * after[0].summary.success:.0f})" if after else ""
    return f"{100 * s.success:5.1f}{first} {100 * s.within_1_05x:5.1f} {100 * s.within_2x:5.1f}"


def _print(title: str, result, began: float) -> None:
    cells = "  ".join(f"{_cell(a):>22}" for a in result.agents)
    print(f"{title:<26} {cells}   {time.time() - began:5.1f} s", flush=True)


def _header(agents) -> None:
    print(f"{'':<26} " + "  ".join(f"{NAMES[a]:>22}" for a in agents))
    print(f"{'':<26} " + "  ".join(f"{'reached (after) 1.05x 2x':>22}" for _ in agents))


def bench_pointer(goals: int, seeds: int) -> None:
    print(f"\npointer: {goals} goals x seeds 0-{seeds - 1}, 10,000 random steps first, budget 100;"
          " % reached (block after the switch), % within 1.05x and 2x the shortest")
    _header(AGENTS)
    for condition in CONDITIONS:
        for seed in range(seeds):
            began = time.time()
            _print(f"{condition} seed {seed}", run_control(ControlConfig(f"pointer:{condition}", goals=goals,
                                                                          seed=seed)), began)
    for seed in range(seeds):
        began = time.time()
        config = ControlConfig("pointer:hardstop", (("bins", 72),), goals=goals, seed=seed)
        _print(f"hardstop 72 bins seed {seed}", run_control(config), began)


GYM = (
    ("FrozenLake 4x4", "gymnasium:FrozenLake-v1", (("map_name", "4x4"), ("is_slippery", False)), 1_000, 5_000),
    ("FrozenLake 8x8", "gymnasium:FrozenLake-v1", (("map_name", "8x8"), ("is_slippery", False)), 2_000, 10_000),
    ("CliffWalking", "gymnasium:CliffWalking-v1", (), 2_000, 10_000),
)


def bench_gym(goals: int, seeds: int) -> None:
    agents = ("slearn", "count-model", "goal-q", "q-one-goal")
    print(f"\nGymnasium, deterministic: {goals} random goal cells (not holes, reachable) x seeds "
          f"0-{seeds - 1}, budget 100; exploration: random steps, then directed steps until every "
          "reachable action was tried")
    _header(agents)
    for title, env, args, trials, directed in GYM:
        for seed in range(seeds):
            began = time.time()
            result = run_control(ControlConfig(env, args, goals=goals, seed=seed, trials=trials,
                                               directed=directed, agents=agents))
            _print(f"{title} seed {seed} ({result.exploration_steps} expl.)", result, began)
    _slippery(goals, seeds)
    _taxi(seeds)


def _slippery(goals: int, seeds: int) -> None:
    agents = ("slearn", "count-model", "goal-q", "true-model")
    print(f"\nslippery FrozenLake 8x8: {goals} random goal cells, budget 100, 100,000 random steps "
          "then directed; a hole sends the agent back to the start (the episode restarts)")
    _header(agents)
    for seed in range(seeds):
        began = time.time()
        result = run_control(ControlConfig("gymnasium:FrozenLake-v1", (("map_name", "8x8"), ("is_slippery", True)),
                                           goals=goals, seed=seed, trials=100_000, directed=5_000, agents=agents))
        _print(f"slippery 8x8 seed {seed}", result, began)


def _taxi(seeds: int) -> None:
    import gymnasium

    taxi = gymnasium.make("Taxi-v4").unwrapped
    delivered = tuple(int(taxi.encode(*taxi.locs[d], d, d)) for d in range(4))
    agents = ("slearn", "count-model", "goal-q")
    print("\nTaxi: 200 passengers delivered one after another (goal: the four delivered states), "
          "budget 200, 5,000 random steps then directed")
    _header(agents)
    for seed in range(seeds):
        began = time.time()
        result = run_control(ControlConfig("gymnasium:Taxi-v4", goal=delivered, repeat_goal=True, goals=200,
                                           seed=seed, trials=5_000, directed=30_000, budget=200, agents=agents))
        _print(f"Taxi seed {seed} ({result.exploration_steps} expl.)", result, began)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--goals", type=int, default=300)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--only", choices=("pointer", "gym"), default=None)
    args = parser.parse_args()
    run_control(ControlConfig("pointer:simple", goals=2, trials=500))  # compile
    if args.only != "gym":
        bench_pointer(args.goals, args.seeds)
    if args.only != "pointer":
        bench_gym(args.goals, args.seeds)


if __name__ == "__main__":
    main()
