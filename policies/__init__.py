"""Active exploration for onlinemap: entropy rewards, policy iteration, exploration loops
(DESIGN.md section 4); navigation to a goal through a changing building (section 8).

>>> import onlinemap as om, policies
>>> model, true_map = policies.exploration_world(p_door=0.01)
>>> frame = policies.explore(model, true_map, "entropy", "rbpf", steps=200, seed=0)  # doctest: +SKIP
"""

from .info_gain import InfoGainExplorer, MacroScore
from .information import expected_information_gain, expected_uncertainty, information_reward, uncertainty
from onlinemap.model import door_cells

from .explore import COLUMNS, Exploration, explore, exploration, explore_env
from .frontier import FrontierExplorer, FrontierPlan
from .navigate import NAVIGATION_COLUMNS, Navigation, navigate, oracle_steps, true_distances
from .navigation import GoalPlan, GoTo, StaticGoTo, check_goal, goal_cell, plan_to_goal
from .mdp import (PolicyIterationResult, action_values, evaluate_policy, move_probabilities, policy_iteration,
                  policy_motion)
from .passability import (blocked_probability, distances_from, distances_to, enter_costs, expected_passability,
                          unblocked_actions)
from .planners import (PLANNERS, EntropyExplorer, Planner, PlannerEntry, RandomWalk, Sweep, make_planner,
                       planner_class, planner_options, sweep_actions)
from .plots import plot_errors, plot_visits
from .rewards import RewardFunction, collected_entropy_reward, entropy_reward
from .worlds import exploration_world, floor_plan_prior, with_floor_plan

__all__ = [
    "entropy_reward", "collected_entropy_reward", "RewardFunction",
    "policy_iteration", "PolicyIterationResult", "action_values", "evaluate_policy", "policy_motion",
    "move_probabilities", "expected_passability", "enter_costs", "distances_to", "distances_from",
    "blocked_probability", "unblocked_actions", "FrontierExplorer", "FrontierPlan",
    "Planner", "EntropyExplorer", "RandomWalk", "Sweep", "make_planner", "sweep_actions", "PLANNERS", "PlannerEntry",
    "planner_options", "planner_class",
    "InfoGainExplorer", "MacroScore", "expected_information_gain", "expected_uncertainty",
    "information_reward", "uncertainty",
    "explore", "exploration", "Exploration", "explore_env", "door_cells", "COLUMNS", "exploration_world", "floor_plan_prior",
    "with_floor_plan", "plot_errors", "plot_visits",
    "GoTo", "StaticGoTo", "GoalPlan", "plan_to_goal", "goal_cell", "check_goal",
    "navigate", "Navigation", "NAVIGATION_COLUMNS", "oracle_steps", "true_distances",
]

#: names that moved to the studies layer: the error says where
MOVED = {"compare_planners": "onlinemap.studies.exploration.compare_planners",
         "summarize": "onlinemap.studies.exploration.summarize_planners",
         "studies": "onlinemap.studies.exploration"}


def __getattr__(name: str):
    if name in MOVED:
        raise AttributeError(f"policies.{name} moved to {MOVED[name]} (studies live in onlinemap.studies, "
                             f"above the planners)")
    raise AttributeError(f"module 'policies' has no attribute {name!r}")
