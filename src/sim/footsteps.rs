//! Where the simulated robot's feet landed against its walking plan's footprints.
//!
//! A sole is down while its site is within [`DOWN_M`] of the floor and moving slower than
//! [`STILL_M_S`] along it, for at least [`STANCE_S`]; each such stance is a footprint. The
//! first of each foot is where it started: the plan's first two footprints and these two set
//! how the plan's floor lies on the simulator's (the midpoint of the feet and their heading).
//! Stances of a foot within [`SAME_PRINT_M`] and [`ROCK_S`] of each other are one footprint
//! (it rocked).
//! Then each foot's stances are matched to its footsteps of the plan in order, least distance
//! overall (an edit distance, a stance or footstep left out costing
//! [`UNMATCHED_M`]), and the error is the distance between the footprint's centre and the
//! stance's mean position.

use glam::DVec2;
use serde::Serialize;

use crate::retarget::walk::FootstepReport;

/// A sole site this close to the floor, or closer, may be down (metres).
pub const DOWN_M: f64 = 0.005;

/// A sole moving slower than this along the floor may be down (m/s).
pub const STILL_M_S: f64 = 0.05;

/// The shortest stance counted, s.
pub const STANCE_S: f64 = 0.05;

/// Two stances of a foot this close (metres) and this little apart in time (s) are one
/// footprint: the foot rocked on it, it did not step.
pub const SAME_PRINT_M: f64 = 0.02;

/// See [`SAME_PRINT_M`].
pub const ROCK_S: f64 = 0.1;

/// What leaving a stance or a footstep unmatched costs when stances are matched to footsteps,
/// metres: a stance this far from every footprint is no footstep of the plan.
pub const UNMATCHED_M: f64 = 0.05;

/// The footsteps' figures.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct FootstepError {
    /// Over the footsteps matched (the starting feet not counted), mm.
    pub rms: f64,
    /// Largest, mm.
    pub max: f64,
    /// Footsteps of the plan the robot took (a stance matched to them).
    pub matched: usize,
    /// Stances of the robot matched to no footstep (extra steps, stumbles).
    pub extra_stances: usize,
    /// Footsteps of the plan no stance was matched to (steps not taken, or landed more than
    /// twice [`UNMATCHED_M`] away).
    pub missed: usize,
}

/// One stance of a foot: its mean position on the floor over its samples.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Stance {
    at: DVec2,
    samples: usize,
    to_s: f64,
}

/// The stances of one sole from its positions `(time, [x, y, z])`, up to `until` s.
fn stances(track: &[(f64, [f64; 3])], until: f64) -> Vec<Stance> {
    let mut out = Vec::new();
    let mut run: Vec<DVec2> = Vec::new();
    let mut from = 0.0;
    let close = |run: &mut Vec<DVec2>, from: f64, to: f64, out: &mut Vec<Stance>| {
        if to - from >= STANCE_S && !run.is_empty() {
            let stance = Stance {
                at: run.iter().copied().sum::<DVec2>() / run.len() as f64,
                samples: run.len(),
                to_s: to,
            };
            match out.last_mut() {
                Some(last)
                    if (last.at - stance.at).length() <= SAME_PRINT_M && from - last.to_s <= ROCK_S =>
                {
                    let n = (last.samples + stance.samples) as f64;
                    last.at = (last.at * last.samples as f64 + stance.at * stance.samples as f64) / n;
                    last.samples += stance.samples;
                    last.to_s = to;
                }
                _ => out.push(stance),
            }
        }
        run.clear();
    };
    for w in track.windows(2) {
        let ((t0, a), (t1, b)) = (w[0], w[1]);
        if t1 > until {
            break;
        }
        let speed = DVec2::new(b[0] - a[0], b[1] - a[1]).length() / (t1 - t0).max(1e-9);
        let down = b[2] <= DOWN_M && speed <= STILL_M_S;
        if down {
            if run.is_empty() {
                from = t1;
            }
            run.push(DVec2::new(b[0], b[1]));
        } else if !run.is_empty() {
            close(&mut run, from, t0, &mut out);
        }
    }
    if let Some((t, _)) = track.last() {
        close(&mut run, from, *t, &mut out);
    }
    out
}

/// How far the floor of `plan` (its first two footprints) is turned and moved onto the
/// simulator's (the first stances): a function from plan to simulator coordinates.
fn placement(plan: [DVec2; 2], sim: [DVec2; 2]) -> impl Fn(DVec2) -> DVec2 {
    let heading = |l: DVec2, r: DVec2| {
        let across = l - r;
        across.y.atan2(across.x)
    };
    let turn = heading(sim[0], sim[1]) - heading(plan[0], plan[1]);
    let (s, c) = turn.sin_cos();
    let (pm, sm) = ((plan[0] + plan[1]) * 0.5, (sim[0] + sim[1]) * 0.5);
    move |p: DVec2| {
        let d = p - pm;
        sm + DVec2::new(c * d.x - s * d.y, s * d.x + c * d.y)
    }
}

/// The footstep error of a walk: `soles` the left and right sole sites' tracks (time, world
/// position), `plan` the plan's footsteps (its first of each side: where the feet start), up
/// to `until` s (a fall). `None` when a foot never stood still.
#[must_use]
pub fn footstep_error(
    soles: [&[(f64, [f64; 3])]; 2],
    plan: &[FootstepReport],
    until: f64,
) -> Option<FootstepError> {
    let side_of = |s: &FootstepReport| usize::from(s.side != "left");
    let sim = soles.map(|t| stances(t, until));
    let planned: [Vec<DVec2>; 2] = [0, 1].map(|side| {
        plan.iter()
            .filter(|s| side_of(s) == side)
            .map(|s| DVec2::new(s.at[0], s.at[1]))
            .collect()
    });
    let start_sim = [sim[0].first()?.at, sim[1].first()?.at];
    let start_plan = [*planned[0].first()?, *planned[1].first()?];
    let to_sim = placement(start_plan, start_sim);
    let (mut sum_sq, mut max, mut matched, mut extra) = (0.0, 0.0f64, 0, 0);
    let steps = planned[0].len() + planned[1].len() - 2;
    for side in 0..2 {
        let prints: Vec<DVec2> = planned[side].iter().map(|p| to_sim(*p)).collect();
        let stances: Vec<DVec2> = sim[side].iter().map(|s| s.at).collect();
        for (i, j) in align(&stances, &prints) {
            match j {
                // The starting feet placed the floors: not a footstep.
                Some(0) => {}
                Some(j) => {
                    let e = (prints[j] - stances[i]).length() * 1e3;
                    sum_sq += e * e;
                    max = max.max(e);
                    matched += 1;
                }
                None => extra += 1,
            }
        }
    }
    Some(FootstepError {
        rms: if matched > 0 {
            (sum_sq / matched as f64).sqrt()
        } else {
            0.0
        },
        max,
        matched,
        extra_stances: extra,
        missed: steps - matched,
    })
}

/// Matches `stances` to `prints` in order (both in time order), each stance to at most one
/// footprint, so that the distances matched plus [`UNMATCHED_M`] for each left out are least
/// (an edit distance): per stance, the footprint it is matched to, if any.
fn align(stances: &[DVec2], prints: &[DVec2]) -> Vec<(usize, Option<usize>)> {
    let (n, m) = (stances.len(), prints.len());
    // cost[i][j]: the least cost of the first i stances against the first j footprints.
    let mut cost = vec![vec![0.0; m + 1]; n + 1];
    for i in 0..=n {
        for j in 0..=m {
            cost[i][j] = match (i, j) {
                (0, 0) => 0.0,
                (0, _) => cost[0][j - 1] + UNMATCHED_M,
                (_, 0) => cost[i - 1][0] + UNMATCHED_M,
                _ => (cost[i - 1][j - 1] + (stances[i - 1] - prints[j - 1]).length())
                    .min(cost[i - 1][j] + UNMATCHED_M)
                    .min(cost[i][j - 1] + UNMATCHED_M),
            };
        }
    }
    let mut out = Vec::with_capacity(n);
    let (mut i, mut j) = (n, m);
    while i > 0 {
        if j > 0 {
            let here = cost[i][j];
            let matched = cost[i - 1][j - 1] + (stances[i - 1] - prints[j - 1]).length();
            if (here - matched).abs() < 1e-12 {
                out.push((i - 1, Some(j - 1)));
                i -= 1;
                j -= 1;
                continue;
            }
            if (here - (cost[i][j - 1] + UNMATCHED_M)).abs() < 1e-12 {
                j -= 1;
                continue;
            }
        }
        out.push((i - 1, None));
        i -= 1;
    }
    out.reverse();
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn step(side: &'static str, x: f64, y: f64) -> FootstepReport {
        FootstepReport {
            side,
            at: [x, y, 0.0],
            ..FootstepReport::default()
        }
    }

    /// A foot down at `x` from `t0` to `t1`, lifted between (1 kHz).
    fn track(stands: &[(f64, f64, f64, f64)]) -> Vec<(f64, [f64; 3])> {
        let mut out = Vec::new();
        let mut t = 0.0;
        while t < 3.0 {
            let down = stands.iter().find(|s| t >= s.0 && t < s.1);
            let p = match down {
                Some(s) => [s.2, s.3, 0.0],
                None => [0.0, 0.0, 0.03],
            };
            out.push((t, p));
            t += 0.001;
        }
        out
    }

    #[test]
    fn steps_on_a_moved_and_turned_floor_match_their_footprints() {
        // The plan's floor: feet at x = 1, y = ±0.05; the simulator's: turned 90°, at the
        // origin. Left steps to x = 1.1 (plan), i.e. y = 0.1 in the simulator, 3 mm off.
        let plan = [
            step("left", 1.0, 0.05),
            step("right", 1.0, -0.05),
            step("left", 1.1, 0.05),
        ];
        let left = track(&[(0.0, 0.5, -0.05, 0.0), (1.0, 3.0, -0.053, 0.1)]);
        let right = track(&[(0.0, 3.0, 0.05, 0.0)]);
        let e = footstep_error([&left, &right], &plan, f64::INFINITY).unwrap();
        assert_eq!((e.matched, e.extra_stances, e.missed), (1, 0, 0));
        assert!((e.rms - 3.0).abs() < 0.1, "{e:?}");
    }

    #[test]
    fn a_stance_beyond_the_plan_counts_as_extra_and_a_fall_ends_the_count() {
        let plan = [step("left", 0.0, 0.05), step("right", 0.0, -0.05)];
        let left = track(&[(0.0, 0.5, 0.0, 0.05), (1.0, 1.5, 0.1, 0.05)]);
        let right = track(&[(0.0, 3.0, 0.0, -0.05)]);
        let e = footstep_error([&left, &right], &plan, f64::INFINITY).unwrap();
        assert_eq!((e.matched, e.extra_stances, e.missed), (0, 1, 0));
        let e = footstep_error([&left, &right], &plan, 0.8).unwrap();
        assert_eq!((e.matched, e.extra_stances, e.missed), (0, 0, 0));
    }

    #[test]
    fn a_step_in_place_and_a_rock_are_told_apart() {
        // The left foot steps in place (lifted 0.4 s), then rocks (off 20 ms), then steps on.
        let plan = [
            step("left", 0.0, 0.05),
            step("right", 0.0, -0.05),
            step("left", 0.0, 0.05),
            step("left", 0.1, 0.05),
        ];
        let left = track(&[
            (0.0, 0.5, 0.0, 0.05),
            (0.9, 1.2, 0.0, 0.05),
            (1.22, 1.5, 0.001, 0.05),
            (2.0, 3.0, 0.104, 0.05),
        ]);
        let right = track(&[(0.0, 3.0, 0.0, -0.05)]);
        let e = footstep_error([&left, &right], &plan, f64::INFINITY).unwrap();
        assert_eq!((e.matched, e.extra_stances, e.missed), (2, 0, 0), "{e:?}");
        assert!((e.max - 4.0).abs() < 0.2, "{e:?}");
    }

    #[test]
    fn no_stance_no_figure() {
        let plan = [step("left", 0.0, 0.05), step("right", 0.0, -0.05)];
        let air = track(&[]);
        assert!(footstep_error([&air, &air], &plan, f64::INFINITY).is_none());
    }
}
