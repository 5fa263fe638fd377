//! A task's group from what it does — its goals and the objects they name — not from its name.
//! The rule, first match wins (each assignment is explained in the mapping report):
//!
//! 1. **piles**: a pile is swept into a zone (`pile_in_zone`).
//! 2. **stacking**: an object goes on top of another (`stacked`, `on_top_of`, the spot of an
//!    object another goal moves, a generator's target 2 cm or more above another within 10
//!    cm), or two objects may go only to the same spot (a tower on a pallet).
//! 3. **sorting**: objects go to two or more different whole places — zones, containers, the
//!    spot of an object no goal moves (each ball into its own box).
//! 4. **assembling**: three or more goals send objects to three or more different spots of one
//!    arrangement, measured from one object or on the table (a line, a wheel, a car, a
//!    bridge).
//! 5. **articulation**: a joint is moved (`joint_position`).
//! 6. **placement**: anything else (an object into a zone, a container or a spot).
//!
//! The destination of a goal is what it is measured from: a zone, a container, a support, the
//! object of `relative_to`, or the table; an `any_of` goes where its first alternative does.

use std::collections::BTreeSet;

use assay_spec::spec::{Goal, TaskSpec};

/// A place a goal may send its object: what it is measured from (`None`: the table) and the
/// spot there, if it names one.
type Place = (Option<String>, Option<[f64; 2]>);

/// Two spots closer than this (m) are the same spot.
const SAME_SPOT: f64 = 0.01;

/// Where goal `g` puts its object: what it is measured from (`None`: the table) and the spot
/// there (x, y), if it names one.
fn destination(g: &Goal) -> Option<(Option<&str>, Option<[f64; 2]>)> {
    match g {
        Goal::InZone { zone, .. } => Some((Some(zone), None)),
        Goal::InContainer { container, .. } => Some((Some(container), None)),
        Goal::OnTopOf { support, .. } => Some((Some(support), Some([0.0, 0.0]))),
        Goal::PoseWithin {
            position,
            relative_to,
            ..
        } => Some((relative_to.as_deref(), Some([position[0], position[1]]))),
        Goal::WithinDistance { target, point, .. } => Some((
            target.as_deref(),
            point
                .map(|p| [p[0], p[1]])
                .or(target.as_ref().map(|_| [0.0, 0.0])),
        )),
        Goal::AnyOf { any } => any.first().and_then(destination),
        Goal::Stacked { .. }
        | Goal::JointPosition { .. }
        | Goal::Lifted { .. }
        | Goal::PileInZone { .. } => None,
    }
}

/// The group of `spec` and why; `above`: how far (m) one of the generator's target poses
/// stands above another beside it, where the generator gives target heights (GenSim; spec
/// goals are checked in x and y only).
pub(crate) fn group_of(spec: &TaskSpec, above: Option<f64>) -> (String, String) {
    let goals = &spec.goals;
    let named = |s: &str, why: String| (s.to_owned(), why);
    if goals.iter().any(|g| matches!(g, Goal::PileInZone { .. })) {
        return named("piles", "a pile is swept into a zone (pile_in_zone)".into());
    }
    if let Some(dz) = above {
        return named(
            "stacking",
            format!(
                "a target stands {:.0} mm above another beside it: objects go on others",
                dz * 1000.0
            ),
        );
    }
    if let Some(g) = goals
        .iter()
        .find(|g| matches!(g, Goal::Stacked { .. } | Goal::OnTopOf { .. }))
    {
        return named(
            "stacking",
            format!("an object goes on another ({})", g.label()),
        );
    }
    // Each goal's object and every place it may go to (all of an any_of's alternatives).
    let alternatives = |g: &Goal| -> Vec<Place> {
        let one = |g: &Goal| destination(g).map(|(a, at)| (a.map(str::to_owned), at));
        match g {
            Goal::AnyOf { any } => any.iter().filter_map(one).collect(),
            g => one(g).into_iter().collect(),
        }
    };
    let moved: BTreeSet<String> = goals.iter().filter_map(goal_object).collect();
    let places: Vec<Vec<Place>> = goals.iter().map(alternatives).collect();
    let on_spot = |at: &Option<[f64; 2]>| at.is_none_or(|p| p[0].hypot(p[1]) < SAME_SPOT);
    // On top of an object a goal also moves: a tower.
    if let Some(a) = places.iter().flatten().find_map(|(a, at)| {
        a.as_ref()
            .filter(|a| moved.contains(a.as_str()) && at.is_some() && on_spot(at))
    }) {
        return named(
            "stacking",
            format!("an object goes on top of '{a}', which a goal also moves"),
        );
    }
    // Two objects that may go only to the same spot: one on the other.
    let single: Vec<&Place> = places
        .iter()
        .filter(|p| p.len() == 1)
        .map(|p| &p[0])
        .collect();
    for (i, (a, p)) in single.iter().map(|x| (&x.0, x.1)).enumerate() {
        let Some(p) = p else { continue };
        if single[i + 1..]
            .iter()
            .any(|(b, q)| a == b && q.is_some_and(|q| (p[0] - q[0]).hypot(p[1] - q[1]) < SAME_SPOT))
        {
            let on = a
                .as_ref()
                .map_or("the table".to_string(), |a| format!("'{a}'"));
            return named(
                "stacking",
                format!("two objects go to the same spot on {on}: one on the other"),
            );
        }
    }
    // Whole places (a zone, a container, an object's own spot): two or more is sorting.
    let whole: BTreeSet<&str> = places
        .iter()
        .filter_map(|p| p.first())
        .filter(|(_, at)| on_spot(at))
        .filter_map(|(a, _)| a.as_deref())
        .collect();
    if whole.len() >= 2 {
        return named(
            "sorting",
            format!(
                "objects go to {} different places ({})",
                whole.len(),
                whole.iter().copied().collect::<Vec<_>>().join(", ")
            ),
        );
    }
    // Spots of one arrangement: three or more, from one object or on the table.
    let mut spots: Vec<(Option<&str>, [f64; 2])> = Vec::new();
    for (a, at) in places.iter().flatten() {
        let Some(p) = at else { continue };
        if !spots
            .iter()
            .any(|(b, q)| *b == a.as_deref() && (p[0] - q[0]).hypot(p[1] - q[1]) < SAME_SPOT)
        {
            spots.push((a.as_deref(), *p));
        }
    }
    let anchors: BTreeSet<Option<&str>> = spots.iter().map(|(a, _)| *a).collect();
    for anchor in anchors {
        let n = spots.iter().filter(|(a, _)| *a == anchor).count();
        if n >= 3 && goals.len() >= 3 {
            let from = anchor.map_or("on the table".to_string(), |a| format!("from '{a}'"));
            return named(
                "assembling",
                format!("objects go to {n} different spots of one arrangement {from}"),
            );
        }
    }
    if goals
        .iter()
        .any(|g| matches!(g, Goal::JointPosition { .. }))
    {
        return named("articulation", "a joint is moved (joint_position)".into());
    }
    named(
        "placement",
        "objects go to a zone, a container or a spot (no stacking, sorting or arrangement)".into(),
    )
}

/// The object goal `g` moves (an any_of's first alternative's).
fn goal_object(g: &Goal) -> Option<String> {
    match g {
        Goal::InZone { object, .. }
        | Goal::InContainer { object, .. }
        | Goal::OnTopOf { object, .. }
        | Goal::WithinDistance { object, .. }
        | Goal::PoseWithin { object, .. }
        | Goal::Lifted { object, .. } => Some(object.clone()),
        Goal::AnyOf { any } => any.first().and_then(goal_object),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use assay_spec::spec::{Format, parse_task};

    fn with_goals(goals: &str) -> TaskSpec {
        let text = assay_testkit::tasks::PUT_BLOCK_IN_ZONE
            .replace(
                "    - {id: red_block,",
                "    - {id: b, shape: {box: {half_extents: [0.02, 0.02, 0.02]}}, pose: {position: [0.4, 0.1, 0.02]}}\n    - {id: c, shape: {box: {half_extents: [0.02, 0.02, 0.02]}}, pose: {position: [0.4, -0.2, 0.02]}}\n    - {id: red_block,",
            )
            .replace("  - in_zone: {object: red_block, zone: goal}\n", goals);
        parse_task(&text, Format::Yaml, "g.yaml").unwrap()
    }

    #[test]
    fn a_group_follows_what_the_goals_do() {
        let spot = |o: &str, x: f64, rel: &str| {
            format!(
                "  - pose_within: {{object: {o}, position: [{x}, 0, 0], tolerance: 0.01, relative_to: {rel}, planar: true}}\n"
            )
        };
        for (goals, above, group) in [
            (
                "  - in_zone: {object: red_block, zone: goal}\n".to_string(),
                None,
                "placement",
            ),
            (
                "  - in_zone: {object: red_block, zone: goal}\n".to_string(),
                Some(0.04),
                "stacking",
            ),
            (
                "  - stacked: {order: [b, red_block]}\n".to_string(),
                None,
                "stacking",
            ),
            (
                spot("red_block", 0.0, "b") + &spot("b", 0.1, "c"),
                None,
                "stacking",
            ),
            (
                spot("red_block", 0.0, "c") + &spot("b", 0.0, "c"),
                None,
                "stacking",
            ),
            (
                "  - in_zone: {object: red_block, zone: goal}\n".to_string() + &spot("b", 0.0, "c"),
                None,
                "sorting",
            ),
            (
                spot("red_block", 0.0, "c") + &spot("b", 0.05, "c") + &spot("red_block", 0.1, "c"),
                None,
                "assembling",
            ),
        ] {
            let spec = with_goals(&goals);
            let (got, why) = group_of(&spec, above);
            assert_eq!(got, group, "{goals}: {why}");
            assert!(!why.is_empty());
        }
    }
}
