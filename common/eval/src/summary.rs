//! Aggregates of evaluation episodes: outcome rates, mean score and time ([`Rates`]), a
//! route's result ([`RouteResult`]), and one room's row ([`RoomSummary`]).

use super::episode::EpisodeResult;
use super::smoothness::CommandStats;
use dvnav_sim::Outcome;
use serde::Serialize;

/// Outcome rates and means over a set of episodes.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Rates {
    /// Episodes counted.
    pub episodes: usize,
    /// Share that reached the goal (NaN, `null` in JSON, with no episodes).
    pub success_rate: f64,
    /// Share that ended in a collision.
    pub collision_rate: f64,
    /// Share that ran out of steps.
    pub timeout_rate: f64,
    /// Mean score S over all episodes (−1 for each failure).
    pub mean_score: f64,
    /// Mean simulated time to the goal (s) over the **successful** episodes only; `None`
    /// (`null`) when none succeeded.
    pub mean_time_s: Option<f64>,
    /// Mean path length (m) over the successful episodes only.
    pub mean_path_length_m: Option<f64>,
    /// Share of control cycles, over all episodes, where ω changed sign by more than ω_max
    /// ([`super::smoothness`]; NaN, `null`, with no cycle).
    pub reversal_rate: f64,
    /// Mean |Δω| per control cycle over all episodes (rad/s).
    pub mean_abs_domega: f64,
    /// Over planned routes (long tasks with `env.subgoals`); absent without them.
    #[serde(flatten)]
    pub routes: Option<RouteRates>,
}

/// Route figures over the episodes of long tasks ([`dvnav_sim::RouteStats`]).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RouteRates {
    /// `planner`: the agent followed the planner's subgoals; `none`: it saw the final goal
    /// only (the path was planned for these figures).
    pub subgoals: &'static str,
    /// Mean planned path length from the start (m), over episodes with a plan.
    pub path_length_m: Option<f64>,
    /// Mean of driven / planned length over the successful episodes with a plan.
    pub path_ratio: Option<f64>,
    /// Mean replans per episode.
    pub replans: f64,
    /// Share of episodes in which some plan found no path.
    pub blocked_rate: f64,
}

/// [`RouteRates`] of `episodes`, when they planned routes.
fn route_rates(episodes: &[EpisodeResult]) -> Option<RouteRates> {
    let routes: Vec<(&EpisodeResult, dvnav_sim::RouteStats)> =
        episodes.iter().filter_map(|e| e.route.map(|r| (e, r))).collect();
    let first = routes.first()?.1;
    let n = routes.len() as f64;
    let mean = |xs: &[f64]| (!xs.is_empty()).then(|| xs.iter().sum::<f64>() / xs.len() as f64);
    let planned: Vec<f64> = routes.iter().filter_map(|(_, r)| r.planned_length_m).collect();
    let ratios: Vec<f64> = routes
        .iter()
        .filter(|(e, _)| e.outcome == Outcome::Success)
        .filter_map(|(e, r)| r.planned_length_m.filter(|&p| p > 0.0).map(|p| e.path_length_m / p))
        .collect();
    Some(RouteRates {
        subgoals: if first.follow { "planner" } else { "none" },
        path_length_m: mean(&planned),
        path_ratio: mean(&ratios),
        replans: routes.iter().map(|(_, r)| r.replans as f64).sum::<f64>() / n,
        blocked_rate: routes.iter().filter(|(_, r)| r.blocked).count() as f64 / n,
    })
}

/// Rates and means of `episodes`.
pub fn aggregate(episodes: &[EpisodeResult]) -> Rates {
    let n = episodes.len();
    let share = |o: Outcome| episodes.iter().filter(|e| e.outcome == o).count() as f64 / n as f64;
    let commands = episodes.iter().fold(CommandStats::default(), |a, e| a.pooled(e.commands));
    let ok: Vec<&EpisodeResult> =
        episodes.iter().filter(|e| e.outcome == Outcome::Success).collect();
    let mean_ok = |f: fn(&EpisodeResult) -> f64| {
        (!ok.is_empty()).then(|| ok.iter().map(|e| f(e)).sum::<f64>() / ok.len() as f64)
    };
    Rates {
        episodes: n,
        success_rate: share(Outcome::Success),
        collision_rate: share(Outcome::Collision),
        timeout_rate: share(Outcome::Timeout),
        mean_score: episodes.iter().map(|e| e.score).sum::<f64>() / n as f64,
        mean_time_s: mean_ok(|e| e.time_s),
        mean_path_length_m: mean_ok(|e| e.path_length_m),
        reversal_rate: commands.reversal_rate(),
        mean_abs_domega: commands.mean_abs_domega(),
        routes: route_rates(episodes),
    }
}

/// One goal of a route.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LegSummary {
    /// The goal (m).
    pub goal: [f64; 2],
    /// How the leg ended; `None` (`null`) when it was not attempted because an earlier leg
    /// failed.
    pub outcome: Option<Outcome>,
    /// Steps of the leg (0 when not attempted).
    pub steps: u32,
    /// Simulated seconds of the leg.
    pub time_s: f64,
    /// Its score S (−1 when not attempted).
    pub score: f64,
}

/// The evaluation route of a room (design §4): from the start, every goal in order, each goal
/// a leg with the full step limit T_max (see [`super::Plan::Route`]).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RouteResult {
    /// Route name.
    pub route: String,
    /// Every goal was reached.
    pub completed: bool,
    /// Goals reached, in order.
    pub goals_reached: usize,
    /// Goals on the route.
    pub goals: usize,
    /// The route's score: the mean of the legs' scores S over all its goals, −1 for each goal
    /// not reached (failed or not attempted). 1 − 2·T̄/T_max for a completed route with mean
    /// leg length T̄ steps.
    pub score: f64,
    /// Simulated seconds over the legs driven.
    pub time_s: f64,
    /// Path length over the legs driven (m).
    pub path_length_m: f64,
    /// Per goal.
    pub legs: Vec<LegSummary>,
}

impl RouteResult {
    /// The result of route `name` with `goals` from the legs that were driven.
    pub fn new(name: &str, goals: &[[f64; 2]], legs: &[EpisodeResult]) -> RouteResult {
        let per_goal: Vec<LegSummary> = goals
            .iter()
            .enumerate()
            .map(|(i, &goal)| match legs.get(i) {
                Some(l) => LegSummary {
                    goal,
                    outcome: Some(l.outcome),
                    steps: l.steps,
                    time_s: l.time_s,
                    score: l.score,
                },
                None => LegSummary { goal, outcome: None, steps: 0, time_s: 0.0, score: -1.0 },
            })
            .collect();
        let reached = per_goal.iter().take_while(|l| l.outcome == Some(Outcome::Success)).count();
        RouteResult {
            route: name.to_string(),
            completed: !goals.is_empty() && reached == goals.len(),
            goals_reached: reached,
            goals: goals.len(),
            score: per_goal.iter().map(|l| l.score).sum::<f64>() / goals.len().max(1) as f64,
            time_s: legs.iter().map(|l| l.time_s).sum(),
            path_length_m: legs.iter().map(|l| l.path_length_m).sum(),
            legs: per_goal,
        }
    }
}

/// One room's (and robot's) evaluation: rates over its random episodes, and its route.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RoomSummary {
    /// Room name.
    pub room: String,
    /// Radius of a circular robot other than the configured one (gate and dynamic scenarios);
    /// absent for the meta robot.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub radius: Option<f64>,
    /// Rates over the room's episodes.
    #[serde(flatten)]
    pub rates: Rates,
    /// The room's route, when it has one.
    pub route: Option<RouteResult>,
}

#[cfg(test)]
mod tests {
    use super::*;
    use dvnav_sim::Pose2;

    fn ep(outcome: Outcome, steps: u32) -> EpisodeResult {
        EpisodeResult {
            room: "r".into(),
            start: Pose2::default(),
            goal: [1.0, 0.0],
            outcome,
            steps,
            time_s: steps as f64 * 0.2,
            path_length_m: steps as f64 * 0.1,
            score: dvnav_sim::score(outcome, steps, 400),
            episode_return: 0.0,
            route: None,
            commands: CommandStats {
                transitions: steps,
                reversals: steps / 10,
                sum_abs_domega: 0.1 * steps as f64,
            },
            trajectory: Vec::new(),
            plan: Vec::new(),
        }
    }

    #[test]
    fn rates_and_means_over_episodes_times_over_successes_only() {
        let eps = [
            ep(Outcome::Success, 100),
            ep(Outcome::Success, 200),
            ep(Outcome::Collision, 10),
            ep(Outcome::Timeout, 400),
        ];
        let r = aggregate(&eps);
        assert_eq!(r.episodes, 4);
        assert_eq!((r.success_rate, r.collision_rate, r.timeout_rate), (0.5, 0.25, 0.25));
        // Scores 0.5, 0.0, −1, −1.
        assert!((r.mean_score - (-0.375)).abs() < 1e-12, "{}", r.mean_score);
        // (20 s + 40 s) / 2: the collision and the timeout do not count.
        assert!((r.mean_time_s.unwrap() - 30.0).abs() < 1e-9);
        assert!((r.mean_path_length_m.unwrap() - 15.0).abs() < 1e-9);
        // Pooled over the 710 cycles of all four episodes, failures included.
        assert!((r.reversal_rate - 71.0 / 710.0).abs() < 1e-12, "{}", r.reversal_rate);
        assert!((r.mean_abs_domega - 0.1).abs() < 1e-12, "{}", r.mean_abs_domega);
        let none = aggregate(&[ep(Outcome::Collision, 5)]);
        assert_eq!((none.mean_time_s, none.mean_score, none.success_rate), (None, -1.0, 0.0));
        let empty = aggregate(&[]);
        assert!(empty.success_rate.is_nan() && empty.mean_score.is_nan());
        let json = serde_json::to_value(&empty).unwrap();
        assert!(json["success_rate"].is_null() && json["mean_time_s"].is_null());
    }

    #[test]
    fn route_score_counts_unreached_goals_as_failures() {
        let goals = [[0.0, 1.0], [1.0, 0.0], [0.0, -1.0], [-1.0, 0.0]];
        let all = [40, 60, 80, 100].map(|s| ep(Outcome::Success, s));
        let r = RouteResult::new("eval", &goals, &all);
        assert!(r.completed);
        assert_eq!((r.goals_reached, r.goals), (4, 4));
        // Mean of 1 − 2·T/400: 1 − 2·70/400 = 0.65.
        assert!((r.score - 0.65).abs() < 1e-12, "{}", r.score);
        assert!((r.time_s - 56.0).abs() < 1e-9);

        let partial = [ep(Outcome::Success, 40), ep(Outcome::Collision, 30)];
        let r = RouteResult::new("eval", &goals, &partial);
        assert!(!r.completed);
        assert_eq!(r.goals_reached, 1);
        assert!((r.score - (0.8 - 3.0) / 4.0).abs() < 1e-12, "{}", r.score);
        let outcomes: Vec<_> = r.legs.iter().map(|l| l.outcome).collect();
        assert_eq!(outcomes, vec![Some(Outcome::Success), Some(Outcome::Collision), None, None]);
        assert!((r.time_s - 14.0).abs() < 1e-9);
    }

    #[test]
    fn room_summary_json_is_flat_with_the_dashboard_names() {
        let s = RoomSummary {
            room: "env0".into(),
            radius: None,
            rates: aggregate(&[ep(Outcome::Success, 100)]),
            route: None,
        };
        let v = serde_json::to_value(&s).unwrap();
        for k in [
            "room",
            "episodes",
            "success_rate",
            "collision_rate",
            "timeout_rate",
            "mean_score",
            "mean_time_s",
        ] {
            assert!(v.get(k).is_some(), "{k} in {v}");
        }
        assert!(v.get("radius").is_none());
        assert_eq!(v["episodes"], 1);
    }
}
