//! Validation of task spec v1: the semantic checks that parsing cannot make — finite numbers
//! within bounds, positive sizes, references that resolve, unique ids, a plan the controller can
//! execute. Every problem names the task, the field path and the reason.
//!
//! Owns: the checks. Never reads a file (asset paths are checked as text here, and against the
//! asset root where they are opened).

use std::collections::BTreeSet;

use super::*;
use crate::error::SpecError;

/// Semantic checks that parsing cannot make: finite numbers, positive sizes, references that
/// resolve, unique ids, a plan the controller can execute.
pub fn validate(spec: &TaskSpec, origin: &str) -> Vec<SpecError> {
    let mut check = Check {
        spec,
        v: Validator {
            task: Some(spec.id.clone()),
            origin,
            errors: Vec::new(),
        },
        object_ids: BTreeSet::new(),
        pile_ids: BTreeSet::new(),
        zone_ids: BTreeSet::new(),
    };
    // Section by section, in the order of the spec: the errors come out in this order.
    check.header();
    check.objects();
    check.piles();
    check.zones();
    check.arm_and_end_effector();
    check.goals();
    check.variations();
    check.plan();
    check.cameras_and_physics();
    check.layouts();
    check.v.errors
}

/// One spec under validation: the errors so far, and the ids the sections before declared (the
/// goals and the plan refer to them).
struct Check<'a> {
    spec: &'a TaskSpec,
    v: Validator<'a>,
    object_ids: BTreeSet<&'a str>,
    pile_ids: BTreeSet<&'a str>,
    zone_ids: BTreeSet<&'a str>,
}

impl<'a> Check<'a> {
    /// The version, the id and the names.
    fn header(&mut self) {
        let (spec, v) = (self.spec, &mut self.v);
        if spec.spec_version != SPEC_VERSION {
            v.err(
                "spec_version",
                format!(
                    "unsupported version {}; this build reads {SPEC_VERSION}",
                    spec.spec_version
                ),
            );
        }
        let id_ok = !spec.id.is_empty()
            && spec
                .id
                .chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '-' || c == '_');
        if !id_ok {
            v.err(
                "id",
                "must be non-empty: lowercase letters, digits, '-' and '_'".into(),
            );
        }
        if spec.name.trim().is_empty() {
            v.err("name", "must not be empty".into());
        }
        if spec.description.trim().is_empty() {
            v.err("description", "must not be empty".into());
        }
        if spec.group.trim().is_empty() {
            v.err("group", "must not be empty".into());
        }
    }

    /// `scene.objects`: unique ids, shapes, masses, colours, a pose or a pose range each.
    fn objects(&mut self) {
        let (spec, v) = (self.spec, &mut self.v);
        if spec.scene.objects.is_empty() && spec.scene.piles.is_empty() {
            v.err("scene.objects", "a task needs at least one object".into());
        }
        for (i, o) in spec.scene.objects.iter().enumerate() {
            let p = format!("scene.objects[{i}]");
            if o.id.is_empty() {
                v.err(&format!("{p}.id"), "must not be empty".into());
            } else if !self.object_ids.insert(o.id.as_str()) {
                v.err(
                    &format!("{p}.id"),
                    format!("duplicate object id '{}'", o.id),
                );
            }
            v.shape(&format!("{p}.shape"), &o.shape);
            if let Some(m) = o.mass {
                v.mass(&format!("{p}.mass"), m);
            }
            if let Some(c) = &o.color {
                v.color(&format!("{p}.color"), c);
            }
            match (&o.pose, &o.pose_range) {
                (Some(pose), None) => {
                    v.finite3(&format!("{p}.pose.position"), &pose.position);
                    v.finite(&format!("{p}.pose.yaw_deg"), pose.yaw_deg);
                }
                (None, Some(r)) => v.range(&format!("{p}.pose_range"), r),
                (Some(_), Some(_)) => v.err(&p, "give either pose or pose_range, not both".into()),
                (None, None) => v.err(&p, "missing pose (or pose_range)".into()),
            }
        }
    }

    /// `scene.piles`: ids unique among piles and objects (their copies' too), counts, shapes,
    /// regions.
    fn piles(&mut self) {
        let (spec, v) = (self.spec, &mut self.v);
        for (i, pile) in spec.scene.piles.iter().enumerate() {
            let p = format!("scene.piles[{i}]");
            if pile.id.is_empty() {
                v.err(&format!("{p}.id"), "must not be empty".into());
            } else if self.object_ids.contains(pile.id.as_str())
                || !self.pile_ids.insert(pile.id.as_str())
            {
                v.err(&format!("{p}.id"), format!("duplicate id '{}'", pile.id));
            }
            if !(1..=MAX_PILE).contains(&pile.count) {
                v.err(
                    &format!("{p}.count"),
                    format!("must lie in 1..={MAX_PILE}, got {}", pile.count),
                );
            }
            if !matches!(
                pile.shape,
                Shape::Box { .. } | Shape::Sphere { .. } | Shape::Cylinder { .. }
            ) {
                v.err(
                    &format!("{p}.shape"),
                    "a pile is made of boxes, spheres or cylinders".into(),
                );
            }
            v.shape(&format!("{p}.shape"), &pile.shape);
            if let Some(c) = &pile.color {
                v.color(&format!("{p}.color"), c);
            }
            if let Some(m) = pile.mass {
                v.mass(&format!("{p}.mass"), m);
            }
            v.finite2(&format!("{p}.region.min"), &pile.region.min);
            v.finite2(&format!("{p}.region.max"), &pile.region.max);
            for k in 0..2 {
                if pile.region.min[k] >= pile.region.max[k] {
                    v.err(
                        &format!("{p}.region"),
                        format!(
                            "min {} is not below max {}",
                            pile.region.min[k], pile.region.max[k]
                        ),
                    );
                }
            }
            for k in 0..pile.count {
                let copy = format!("{}_{k}", pile.id);
                if self.object_ids.contains(copy.as_str()) {
                    v.err(
                        &format!("{p}.id"),
                        format!("copy '{copy}' has the id of an object"),
                    );
                }
            }
        }
    }

    /// `scene.zones`: unique ids, centres, positive half extents.
    fn zones(&mut self) {
        let (spec, v) = (self.spec, &mut self.v);
        for (i, z) in spec.scene.zones.iter().enumerate() {
            let p = format!("scene.zones[{i}]");
            if !self.zone_ids.insert(z.id.as_str()) || self.object_ids.contains(z.id.as_str()) {
                v.err(&format!("{p}.id"), format!("duplicate id '{}'", z.id));
            }
            v.finite2(&format!("{p}.center"), &z.center);
            for (k, h) in z.half_extents.iter().enumerate() {
                v.positive(&format!("{p}.half_extents[{k}]"), *h);
            }
        }
    }

    /// `arm` (a built-in model, its base) and `end_effector`.
    fn arm_and_end_effector(&mut self) {
        let (spec, v) = (self.spec, &mut self.v);
        if let Some(arm) = &spec.arm {
            if !ARM_MODELS.contains(&arm.model.as_str()) {
                v.err(
                    "arm.model",
                    format!(
                        "unknown arm '{}' (built in: {})",
                        arm.model,
                        ARM_MODELS.join(", ")
                    ),
                );
            }
            v.finite3("arm.base", &arm.base);
            v.finite("arm.base_yaw_deg", arm.base_yaw_deg);
        }
        match spec.end_effector {
            EndEffector::Suction => {}
            EndEffector::ParallelGripper { max_opening, .. } => {
                v.positive("end_effector.max_opening", max_opening)
            }
        }
    }

    /// Whether `id` is a container object.
    fn is_container(&self, id: &str) -> bool {
        self.spec
            .scene
            .objects
            .iter()
            .any(|o| o.id == id && matches!(o.shape, Shape::Container { .. }))
    }

    /// A reference to an object at `path`.
    fn object_ref(&mut self, path: &str, id: &str) {
        if !self.object_ids.contains(id) {
            self.v.err(path, format!("refers to unknown object '{id}'"));
        }
    }

    /// A reference to a zone at `path`.
    fn zone_ref(&mut self, path: &str, zone: &str) {
        if !self.zone_ids.contains(zone) {
            self.v.err(path, format!("refers to unknown zone '{zone}'"));
        }
    }

    /// A reference to a pile at `path`.
    fn pile_ref(&mut self, path: &str, pile: &str) {
        if !self.pile_ids.contains(pile) {
            self.v.err(path, format!("refers to unknown pile '{pile}'"));
        }
    }

    /// Joint goals and `actuate` need an articulated URDF object (its joint names are checked
    /// when the URDF is read).
    fn articulated_ref(&mut self, path: &str, id: &str) {
        match self.spec.object(id) {
            None => self.v.err(path, format!("refers to unknown object '{id}'")),
            Some(o)
                if !matches!(
                    o.shape,
                    Shape::Urdf {
                        articulated: true,
                        ..
                    }
                ) =>
            {
                self.v.err(
                    path,
                    format!(
                        "'{id}' is not an articulated URDF object (urdf with articulated: true)"
                    ),
                )
            }
            Some(_) => {}
        }
    }

    /// `goals`: at least one; `any_of` holds goals checked like the others, one level deep.
    fn goals(&mut self) {
        let spec = self.spec;
        if spec.goals.is_empty() {
            self.v
                .err("goals", "a task needs at least one goal predicate".into());
        }
        let mut flat: Vec<(String, &Goal)> = Vec::new();
        for (i, g) in spec.goals.iter().enumerate() {
            match g {
                Goal::AnyOf { any } => {
                    if any.is_empty() {
                        self.v.err(
                            &format!("goals[{i}].any_of.any"),
                            "needs at least one goal".into(),
                        );
                    }
                    for (k, inner) in any.iter().enumerate() {
                        flat.push((format!("goals[{i}].any_of.any[{k}]"), inner));
                    }
                }
                g => flat.push((format!("goals[{i}]"), g)),
            }
        }
        for (p, g) in &flat {
            self.goal(p, g);
        }
        for (i, step) in spec.reward_steps.iter().enumerate() {
            let p = format!("reward_steps[{i}]");
            self.v
                .within(&format!("{p}.max_reward"), step.max_reward, 0.0, 1e6, "");
            if step.goals.is_empty() {
                self.v.err(
                    &format!("{p}.goals"),
                    "a step needs at least one goal".into(),
                );
            }
            for (k, g) in step.goals.iter().enumerate() {
                match g {
                    Goal::AnyOf { any } => {
                        for (j, inner) in any.iter().enumerate() {
                            self.goal(&format!("{p}.goals[{k}].any_of.any[{j}]"), inner);
                        }
                    }
                    g => self.goal(&format!("{p}.goals[{k}]"), g),
                }
            }
        }
    }

    /// One goal at path `p`.
    fn goal(&mut self, p: &str, g: &Goal) {
        match g {
            Goal::AnyOf { .. } => self.v.err(
                &format!("{p}.any_of"),
                "an any_of goal cannot hold another any_of".into(),
            ),
            Goal::InZone { object, zone } => {
                self.object_ref(&format!("{p}.in_zone.object"), object);
                self.zone_ref(&format!("{p}.in_zone.zone"), zone);
            }
            Goal::InContainer { object, container } => {
                self.in_container_goal(&format!("{p}.in_container"), object, container)
            }
            Goal::OnTopOf { object, support } => {
                self.object_ref(&format!("{p}.on_top_of.object"), object);
                self.object_ref(&format!("{p}.on_top_of.support"), support);
                if object == support {
                    self.v.err(
                        &format!("{p}.on_top_of"),
                        "an object cannot rest on itself".into(),
                    );
                }
            }
            Goal::Stacked { order } => self.stacked_goal(&format!("{p}.stacked.order"), order),
            Goal::WithinDistance {
                object,
                target,
                point,
                distance,
            } => self.within_distance_goal(
                &format!("{p}.within_distance"),
                object,
                target.as_deref(),
                point.as_ref(),
                *distance,
            ),
            Goal::PoseWithin { .. } => self.pose_within_goal(&format!("{p}.pose_within"), g),
            Goal::JointPosition {
                object,
                joint,
                min,
                max,
            } => {
                self.joint_position_goal(&format!("{p}.joint_position"), object, joint, *min, *max)
            }
            Goal::Lifted { object, height } => {
                self.object_ref(&format!("{p}.lifted.object"), object);
                self.v.positive(&format!("{p}.lifted.height"), *height);
            }
            Goal::PileInZone {
                pile,
                zone,
                fraction,
            } => {
                self.pile_ref(&format!("{p}.pile_in_zone.pile"), pile);
                self.zone_ref(&format!("{p}.pile_in_zone.zone"), zone);
                if !(fraction.is_finite() && *fraction > 0.0 && *fraction <= 1.0) {
                    self.v.err(
                        &format!("{p}.pile_in_zone.fraction"),
                        format!("must lie in (0, 1], got {fraction}"),
                    );
                }
            }
        }
    }

    /// An `in_container` goal at path `p`: both objects known, the container one.
    fn in_container_goal(&mut self, p: &str, object: &str, container: &str) {
        self.object_ref(&format!("{p}.object"), object);
        self.object_ref(&format!("{p}.container"), container);
        if self.object_ids.contains(container) && !self.is_container(container) {
            self.v.err(
                &format!("{p}.container"),
                format!("'{container}' is not a container"),
            );
        }
    }

    /// A `stacked` goal's `order` at path `p`: two objects or more, each known and there once.
    fn stacked_goal(&mut self, p: &str, order: &[String]) {
        if order.len() < 2 {
            self.v.err(p, "needs at least two objects".into());
        }
        let mut seen = BTreeSet::new();
        for (k, o) in order.iter().enumerate() {
            self.object_ref(&format!("{p}[{k}]"), o);
            if !seen.insert(o) {
                self.v
                    .err(&format!("{p}[{k}]"), format!("'{o}' appears twice"));
            }
        }
    }

    /// A `within_distance` goal at path `p`: a known object, exactly one of a known target and a
    /// point, a positive distance.
    fn within_distance_goal(
        &mut self,
        p: &str,
        object: &str,
        target: Option<&str>,
        point: Option<&[f64; 3]>,
        distance: f64,
    ) {
        self.object_ref(&format!("{p}.object"), object);
        match (target, point) {
            (Some(t), None) => self.object_ref(&format!("{p}.target"), t),
            (None, Some(pt)) => self.v.finite3(&format!("{p}.point"), pt),
            _ => self.v.err(p, "give exactly one of target and point".into()),
        }
        self.v.positive(&format!("{p}.distance"), distance);
    }

    /// A `pose_within` goal `g` at path `p` (another goal is not looked at): known objects, a
    /// finite target, a positive tolerance, yaw and its tolerance together.
    fn pose_within_goal(&mut self, p: &str, g: &Goal) {
        let Goal::PoseWithin {
            object,
            position,
            tolerance,
            yaw_deg,
            yaw_tolerance_deg,
            relative_to,
            planar: _,
            yaw_symmetry_deg,
        } = g
        else {
            return;
        };
        self.object_ref(&format!("{p}.object"), object);
        if let Some(anchor) = relative_to {
            self.object_ref(&format!("{p}.relative_to"), anchor);
            if anchor == object {
                self.v.err(
                    &format!("{p}.relative_to"),
                    "a target cannot be measured from the object itself".into(),
                );
            }
        }
        if let Some(s) = yaw_symmetry_deg {
            self.v
                .within(&format!("{p}.yaw_symmetry_deg"), *s, 1.0, 360.0, "°");
        }
        self.v.finite3(&format!("{p}.position"), position);
        self.v.positive(&format!("{p}.tolerance"), *tolerance);
        if yaw_deg.is_some() != yaw_tolerance_deg.is_some() {
            self.v
                .err(p, "yaw_deg and yaw_tolerance_deg go together".into());
        }
    }

    /// A `joint_position` goal at path `p`: an articulated object, a joint name, finite bounds
    /// in order.
    fn joint_position_goal(
        &mut self,
        p: &str,
        object: &str,
        joint: &str,
        min: Option<f64>,
        max: Option<f64>,
    ) {
        self.articulated_ref(&format!("{p}.object"), object);
        if joint.is_empty() {
            self.v
                .err(&format!("{p}.joint"), "must not be empty".into());
        }
        match (min, max) {
            (None, None) => self.v.err(p, "give min, max or both".into()),
            (Some(lo), Some(hi)) if lo > hi => self.v.err(p, format!("min {lo} exceeds max {hi}")),
            _ => {}
        }
        for (k, x) in [("min", min), ("max", max)] {
            if let Some(x) = x {
                self.v.finite(&format!("{p}.{k}"), x);
            }
        }
    }

    /// `variations`: jitter bounds, the start range, a palette with objects to recolour.
    fn variations(&mut self) {
        let (spec, v) = (self.spec, &mut self.v);
        v.within(
            "variations.position_jitter",
            spec.variations.position_jitter,
            0.0,
            MAX_JITTER_M,
            "m",
        );
        v.within(
            "variations.yaw_jitter_deg",
            spec.variations.yaw_jitter_deg,
            0.0,
            180.0,
            "degrees",
        );
        if let Some(r) = &spec.variations.ee_start {
            v.range("variations.ee_start", r);
        }
        for (i, c) in spec.variations.colors.iter().enumerate() {
            v.color(&format!("variations.colors[{i}]"), c);
        }
        match (
            spec.variations.colors.is_empty(),
            spec.variations.recolor.is_empty(),
        ) {
            (false, true) => v.err(
                "variations.colors",
                "no object is recoloured: name the objects that draw from this palette in variations.recolor".into(),
            ),
            (true, false) => v.err(
                "variations.recolor",
                "needs a palette to draw from in variations.colors".into(),
            ),
            _ => {}
        }
        for (i, id) in spec.variations.recolor.iter().enumerate() {
            self.object_ref(&format!("variations.recolor[{i}]"), id);
        }
    }

    /// `layouts`: at most [`MAX_LAYOUTS`], one per seed; each an error with nothing else, or a
    /// scene with its goals and plan that validate as the spec's own do (its errors under
    /// `layouts[i]`).
    fn layouts(&mut self) {
        let spec = self.spec;
        if spec.layouts.len() > MAX_LAYOUTS {
            self.v.err(
                "layouts",
                format!("{} layouts: at most {MAX_LAYOUTS}", spec.layouts.len()),
            );
            return;
        }
        let mut seen = BTreeSet::new();
        for (i, l) in spec.layouts.iter().enumerate() {
            let p = format!("layouts[{i}]");
            if !seen.insert(l.seed) {
                self.v.err(
                    &format!("{p}.seed"),
                    format!("seed {} laid out twice", l.seed),
                );
            }
            match (&l.error, &l.scene) {
                (Some(e), _) if e.trim().is_empty() || e.len() > 2000 => self.v.err(
                    &format!("{p}.error"),
                    "must say why, in at most 2000 bytes".into(),
                ),
                (Some(_), scene) => {
                    if scene.is_some()
                        || !l.goals.is_empty()
                        || !l.oracle.is_empty()
                        || !l.reward_steps.is_empty()
                    {
                        self.v.err(
                            &p,
                            "a layout with an error has no scene, goals or oracle".into(),
                        );
                    }
                }
                (None, None) => self.v.err(
                    &format!("{p}.scene"),
                    "a layout needs a scene (or an error)".into(),
                ),
                (None, Some(_)) => {
                    let laid = spec.with_layout(l.seed).expect("a layout with a scene");
                    for e in validate(&laid, self.v.origin) {
                        self.v.err(&format!("{p}.{}", e.path), e.reason);
                    }
                }
            }
        }
    }

    /// `oracle`: the plan must be executable: pick before place, one object held at a time.
    fn plan(&mut self) {
        let spec = self.spec;
        let mut held: Option<&str> = None;
        for (i, step) in spec.oracle.iter().enumerate() {
            self.step(&format!("oracle[{i}]"), step, &mut held);
        }
        // A plan may end holding what a `lifted` goal wants held up; nothing else.
        if let Some(h) = held
            && !spec
                .goals
                .iter()
                .any(|g| matches!(g, Goal::Lifted { object, .. } if object == h))
        {
            self.v.err(
                "oracle",
                "the plan ends holding an object: add a place (or a lifted goal on it)".into(),
            );
        }
    }

    /// One step of the plan at path `p`, with `held` what the plan holds before it (after it,
    /// once it returns).
    fn step(&mut self, p: &str, step: &'a Primitive, held: &mut Option<&'a str>) {
        match step {
            Primitive::Pick { object } => {
                self.object_ref(&format!("{p}.pick.object"), object);
                if held.is_some() {
                    self.v.err(
                        &format!("{p}.pick"),
                        "already holding an object; place it first".into(),
                    );
                }
                if self
                    .spec
                    .scene
                    .objects
                    .iter()
                    .any(|o| &o.id == object && o.is_fixed)
                {
                    self.v.err(
                        &format!("{p}.pick.object"),
                        format!("'{object}' is fixed and cannot be picked"),
                    );
                }
                *held = Some(object);
            }
            Primitive::Place { target } => {
                let Some(h) = held.take() else {
                    self.v.err(
                        &format!("{p}.place"),
                        "nothing is held: pick an object first".into(),
                    );
                    return;
                };
                self.place_target(&format!("{p}.place.target"), target, h);
            }
            Primitive::Turn {
                yaw_deg,
                symmetry_deg,
            } => {
                self.v.within(
                    &format!("{p}.turn.yaw_deg"),
                    *yaw_deg,
                    -360.0,
                    360.0,
                    "degrees",
                );
                if let Some(s) = symmetry_deg {
                    self.v
                        .within(&format!("{p}.turn.symmetry_deg"), *s, 1.0, 360.0, "degrees");
                }
                if held.is_none() {
                    self.v.err(
                        &format!("{p}.turn"),
                        "nothing is held: pick an object first".into(),
                    );
                }
            }
            Primitive::Push { object, to } => {
                self.object_ref(&format!("{p}.push.object"), object);
                self.v.finite2(&format!("{p}.push.to"), to);
                if held.is_some() {
                    self.v.err(
                        &format!("{p}.push"),
                        "cannot push while holding an object".into(),
                    );
                }
            }
            Primitive::Sweep { pile, zone } => {
                self.pile_ref(&format!("{p}.sweep.pile"), pile);
                self.zone_ref(&format!("{p}.sweep.zone"), zone);
                if held.is_some() {
                    self.v.err(
                        &format!("{p}.sweep"),
                        "cannot sweep while holding an object".into(),
                    );
                }
            }
            Primitive::Actuate { object, joint, to } => {
                self.articulated_ref(&format!("{p}.actuate.object"), object);
                if joint.is_empty() {
                    self.v
                        .err(&format!("{p}.actuate.joint"), "must not be empty".into());
                }
                self.v.finite(&format!("{p}.actuate.to"), *to);
                if held.is_some() {
                    self.v.err(
                        &format!("{p}.actuate"),
                        "cannot actuate a joint while holding an object".into(),
                    );
                }
            }
        }
    }

    /// The target of a place at path `p`, while the plan holds `h`.
    fn place_target(&mut self, p: &str, target: &PlaceTarget, h: &str) {
        match target {
            PlaceTarget::On(o) => {
                self.object_ref(&format!("{p}.on"), o);
                if o == h {
                    self.v.err(
                        &format!("{p}.on"),
                        "cannot place an object on itself".into(),
                    );
                }
            }
            PlaceTarget::Into(o) => {
                self.object_ref(&format!("{p}.into"), o);
                if self.object_ids.contains(o.as_str()) && !self.is_container(o) {
                    self.v
                        .err(&format!("{p}.into"), format!("'{o}' is not a container"));
                }
            }
            PlaceTarget::Zone(z) => self.zone_ref(&format!("{p}.zone"), z),
            PlaceTarget::At(xy) => self.v.finite2(&format!("{p}.at"), xy),
            PlaceTarget::AtPoint(xyz) => self.v.finite3(&format!("{p}.at_point"), xyz),
            PlaceTarget::Spot { xy, relative_to } => {
                self.v.finite2(&format!("{p}.spot.xy"), xy);
                if let Some(o) = relative_to {
                    self.object_ref(&format!("{p}.spot.relative_to"), o);
                    if o == h {
                        self.v.err(
                            &format!("{p}.spot.relative_to"),
                            "cannot place an object beside itself".into(),
                        );
                    }
                }
            }
        }
    }

    /// `cameras` (finite eye and target, a field of view, a size) and `physics.dt`.
    fn cameras_and_physics(&mut self) {
        let (spec, v) = (self.spec, &mut self.v);
        for (i, c) in spec.cameras.iter().enumerate() {
            let p = format!("cameras[{i}]");
            v.finite3(&format!("{p}.eye"), &c.eye);
            v.finite3(&format!("{p}.target"), &c.target);
            if !(c.fovy_deg > 1.0 && c.fovy_deg < 179.0) {
                v.err(
                    &format!("{p}.fovy_deg"),
                    "must lie between 1 and 179 degrees".into(),
                );
            }
            if c.width == 0 || c.height == 0 {
                v.err(&p, "width and height must be positive".into());
            }
        }
        let ph = &spec.physics;
        if !(ph.dt.is_finite() && ph.dt > 0.0 && ph.dt <= 0.05) {
            v.err(
                "physics.dt",
                format!("must lie in (0, 0.05] s, got {}", ph.dt),
            );
        }
    }
}

/// Positions (m) lie within this distance of the table's origin on every axis: the robot's
/// workspace is a metre across, so a larger number is a mistake that physics would turn into NaN.
pub const MAX_POSITION_M: f64 = 10.0;
/// Smallest object size (half extent, radius, wall), 1 mm: smaller bodies fall through contacts
/// and make success trivially true or false.
pub const MIN_SIZE_M: f64 = 0.001;
/// Largest object size, tolerance or distance.
pub const MAX_SIZE_M: f64 = 5.0;
/// Masses between 1 g and 1 t.
pub const MIN_MASS_KG: f64 = 0.001;
pub const MAX_MASS_KG: f64 = 1000.0;
/// Position jitter at most 0.5 m.
pub const MAX_JITTER_M: f64 = 0.5;

/// A number as people read it: `0.02`, and `1e308` rather than 309 digits.
fn show(x: f64) -> String {
    let plain = format!("{x}");
    if plain.len() > 12 {
        format!("{x:e}")
    } else {
        plain
    }
}

struct Validator<'a> {
    task: Option<String>,
    origin: &'a str,
    errors: Vec<SpecError>,
}

impl Validator<'_> {
    fn err(&mut self, path: &str, reason: String) {
        self.errors.push(SpecError {
            task: self.task.clone(),
            origin: self.origin.to_owned(),
            path: path.to_owned(),
            reason,
        });
    }
    fn finite(&mut self, path: &str, x: f64) {
        if !x.is_finite() {
            self.err(path, format!("must be a finite number, got {x}"));
        }
    }
    /// A position (m): finite and within ±[`MAX_POSITION_M`] of the table's origin.
    fn coordinate(&mut self, path: &str, x: f64) {
        if !x.is_finite() {
            self.err(path, format!("must be a finite number, got {}", show(x)));
        } else if x.abs() > MAX_POSITION_M {
            self.err(
                path,
                format!(
                    "must lie within ±{MAX_POSITION_M} m of the origin, got {}",
                    show(x)
                ),
            );
        }
    }
    fn finite2(&mut self, path: &str, x: &[f64; 2]) {
        for (k, c) in x.iter().enumerate() {
            self.coordinate(&format!("{path}[{k}]"), *c);
        }
    }
    fn finite3(&mut self, path: &str, x: &[f64; 3]) {
        for (k, c) in x.iter().enumerate() {
            self.coordinate(&format!("{path}[{k}]"), *c);
        }
    }
    /// A positive length, a tolerance or a distance (m), at most [`MAX_SIZE_M`].
    fn positive(&mut self, path: &str, x: f64) {
        if !(x.is_finite() && x > 0.0) {
            self.err(path, format!("must be a positive number, got {}", show(x)));
        } else if x > MAX_SIZE_M {
            self.err(
                path,
                format!("must be at most {MAX_SIZE_M} m, got {}", show(x)),
            );
        }
    }
    /// An object's size (half extent, radius, wall): between [`MIN_SIZE_M`] and [`MAX_SIZE_M`],
    /// what the simulator resolves and the table holds.
    fn size(&mut self, path: &str, x: f64) {
        self.within(path, x, MIN_SIZE_M, MAX_SIZE_M, "m");
    }
    /// A mass (kg), between [`MIN_MASS_KG`] and [`MAX_MASS_KG`].
    fn mass(&mut self, path: &str, x: f64) {
        self.within(path, x, MIN_MASS_KG, MAX_MASS_KG, "kg");
    }
    /// A finite number in `[lo, hi]`; the error says the bound and the unit.
    fn within(&mut self, path: &str, x: f64, lo: f64, hi: f64, unit: &str) {
        if !x.is_finite() {
            self.err(path, format!("must be a finite number, got {}", show(x)));
        } else if x < lo || x > hi {
            self.err(
                path,
                format!("must lie between {lo} and {hi} {unit}, got {}", show(x)),
            );
        }
    }
    /// A colour name Assay knows, or RGB components in 0..1.
    fn color(&mut self, path: &str, c: &Color) {
        match c.rgb() {
            None => self.err(path, format!("unknown colour {c:?}")),
            Some(rgb) if rgb.iter().any(|x| !(0.0..=1.0).contains(x)) => {
                self.err(path, "rgb components must lie in 0..1".into())
            }
            Some(_) => {}
        }
    }

    /// An asset path: relative, and staying inside the asset root as written.
    fn asset(&mut self, path: &str, file: &str) {
        if let Err(reason) = check_asset_path(file) {
            self.err(path, reason);
        }
    }

    fn range(&mut self, path: &str, r: &PoseRange) {
        self.finite3(&format!("{path}.min"), &r.min);
        self.finite3(&format!("{path}.max"), &r.max);
        for (k, y) in r.yaw_deg.iter().enumerate() {
            self.finite(&format!("{path}.yaw_deg[{k}]"), *y);
        }
        for k in 0..3 {
            if r.min[k] > r.max[k] {
                self.err(
                    &format!("{path}.min[{k}]"),
                    format!("min {} exceeds max {}", r.min[k], r.max[k]),
                );
            }
        }
        if r.yaw_deg[0] > r.yaw_deg[1] {
            self.err(&format!("{path}.yaw_deg"), "min exceeds max".into());
        }
    }
    fn shape(&mut self, path: &str, s: &Shape) {
        match s {
            Shape::Box { half_extents } => {
                for (k, h) in half_extents.iter().enumerate() {
                    self.size(&format!("{path}.box.half_extents[{k}]"), *h);
                }
            }
            Shape::Sphere { radius } => self.size(&format!("{path}.sphere.radius"), *radius),
            Shape::Cylinder {
                radius,
                half_height,
            } => {
                self.size(&format!("{path}.cylinder.radius"), *radius);
                self.size(&format!("{path}.cylinder.half_height"), *half_height);
            }
            Shape::Container {
                inner_half_extents,
                wall,
            } => {
                for (k, h) in inner_half_extents.iter().enumerate() {
                    self.size(&format!("{path}.container.inner_half_extents[{k}]"), *h);
                }
                self.size(&format!("{path}.container.wall"), *wall);
            }
            Shape::Mesh {
                path: file, scale, ..
            } => {
                self.asset(&format!("{path}.mesh.path"), file);
                self.within(&format!("{path}.mesh.scale"), *scale, 1e-6, 1e3, "×");
            }
            Shape::Urdf {
                path: file,
                joints,
                fill,
                ..
            } => {
                self.asset(&format!("{path}.urdf.path"), file);
                for (name, q) in joints {
                    self.finite(&format!("{path}.urdf.joints.{name}"), *q);
                }
                for (key, value) in fill {
                    if let Err(reason) = super::check_fill(key, value) {
                        self.err(&format!("{path}.urdf.fill.{key}"), reason);
                    }
                }
            }
        }
    }
}
