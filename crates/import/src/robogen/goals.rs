//! The goals and the oracle plan of a RoboGen task, inferred from its solution folder: the text
//! of the substeps (and the joint and link names the solution code uses). Opening or closing a
//! lid or a door becomes a joint goal on an articulated URDF and an `actuate`; "put the X into
//! (or on) the Y" a placement goal with a pick and a place. Never reads the scene's items
//! (`objects` does).

use std::collections::BTreeSet;

use super::{Obj, Solution, TaskYaml};
use crate::{r3, r6};
use assay_spec::spec::{Goal, PlaceTarget, Primitive, Shape};
use assay_spec::urdf::{Geometry, Joint, JointKind};

/// A solution's substeps, one a line, with their kinds (`primitive`, `reward`), and its code.
struct Substeps {
    steps: Vec<String>,
    kinds: Vec<String>,
    py_text: String,
}

impl TaskYaml<'_> {
    /// The goals and the oracle of task `name` from `solution`, once the scene is read; none
    /// when a problem already rules the spec out.
    pub(super) fn infer_goals(&mut self, name: &str, solution: &Solution) {
        let sub = self.substeps(solution);
        if self.fatal {
            return;
        }
        let text = format!("{} {}", sub.steps.join(" "), name).to_lowercase();
        let urdf_with_joints: Vec<usize> = self.objs.iter().enumerate().filter(|(_, o)| matches!(&o.object.shape, Shape::Urdf { joints, .. } if !joints.is_empty())).map(|(k, _)| k).collect();
        let joint_task = (text.contains("open") || text.contains("close"))
            && !text.contains(" into ")
            && !urdf_with_joints.is_empty();
        if joint_task {
            self.joint_goal(&text, &urdf_with_joints, &sub);
        } else {
            self.placement_goal(&sub);
        }
    }

    /// The solution's substeps and code, and the notes on its files.
    fn substeps(&mut self, solution: &Solution) -> Substeps {
        let lines = |b: &[u8]| -> Vec<String> {
            String::from_utf8_lossy(b)
                .lines()
                .map(|l| l.trim().to_owned())
                .filter(|l| !l.is_empty())
                .collect()
        };
        let (steps, kinds) = (lines(&solution.substeps), lines(&solution.types));
        if solution.dir.is_none() || steps.is_empty() {
            self.fail("solution_path", "no substeps: the goal cannot be inferred");
        }
        self.notes.not_mapped(
            "action_spaces.txt",
            "RL action spaces of the reward substeps: Assay's oracle is scripted",
        );
        if !solution.py.is_empty() {
            self.notes.not_mapped("substeps *.py", "RoboGen's primitive and reward code (success tests): the goal is inferred from the substep text instead");
        }
        let py_text: String = solution
            .py
            .iter()
            .map(|(_, b)| String::from_utf8_lossy(b).into_owned())
            .collect();
        Substeps {
            steps,
            kinds,
            py_text,
        }
    }

    /// A lid or door task (`text`: the substeps and the name): the joint of the URDF object
    /// the text names (else the first of `urdf_with_joints`) opened or closed.
    fn joint_goal(&mut self, text: &str, urdf_with_joints: &[usize], sub: &Substeps) {
        let opening = sub
            .steps
            .iter()
            .zip(sub.kinds.iter().chain(std::iter::repeat(&String::new())))
            .filter(|(_, k)| *k == "reward")
            .any(|(s, _)| s.to_lowercase().starts_with("open"))
            || (!text.contains("close") && text.contains("open"));
        let k = urdf_with_joints
            .iter()
            .copied()
            .find(|&k| text.contains(&self.objs[k].name.to_lowercase()))
            .unwrap_or(urdf_with_joints[0]);
        match self.moved_joint(k, &sub.py_text) {
            None => {
                let reason = format!(
                    "cannot tell which joint of '{}' the task moves",
                    self.objs[k].name
                );
                self.fail("substeps", reason);
            }
            Some(j) => self.add_joint_goal(k, &j, opening, &sub.steps),
        }
    }

    /// The joint of object `k` the task moves: the joint the solution code (`py_text`) names,
    /// or the joint of a link it names, or the only one.
    fn moved_joint(&self, k: usize, py_text: &str) -> Option<Joint> {
        let (_, u) = self.objs[k].urdf.as_ref().expect("urdf");
        let movable: Vec<&Joint> = u
            .joints
            .iter()
            .filter(|j| {
                matches!(j.kind, JointKind::Revolute | JointKind::Prismatic) && j.limit.is_some()
            })
            .collect();
        movable
            .iter()
            .find(|j| py_text.contains(&format!("\"{}\"", j.name)))
            .or_else(|| {
                movable
                    .iter()
                    .find(|j| py_text.contains(&format!("\"{}\"", u.links[j.child].name)))
            })
            .or(if movable.len() == 1 {
                movable.first()
            } else {
                None
            })
            .map(|j| (*j).clone())
    }

    /// Joint `j` of object `k` opened beyond 0.6 of its range, or closed below 0.15: the goal,
    /// and an `actuate` to 0.85 or 0.02; the object becomes articulated.
    fn add_joint_goal(&mut self, k: usize, j: &Joint, opening: bool, steps: &[String]) {
        let o = &self.objs[k];
        let oid = o.id.clone();
        let [lo, hi] = j.limit.expect("limit");
        let range = hi - lo;
        let q0 = match &o.object.shape {
            Shape::Urdf { joints, .. } => joints.get(&j.name).copied().unwrap_or(lo),
            _ => lo,
        };
        let (goal, to) = if opening {
            (
                Goal::JointPosition {
                    object: oid.clone(),
                    joint: j.name.clone(),
                    min: Some(r6(lo + 0.6 * range)),
                    max: None,
                },
                r6(lo + 0.85 * range),
            )
        } else {
            (
                Goal::JointPosition {
                    object: oid.clone(),
                    joint: j.name.clone(),
                    min: None,
                    max: Some(r6(lo + 0.15 * range)),
                },
                r6(lo + 0.02 * range),
            )
        };
        let already = match &goal {
            Goal::JointPosition { min: Some(m), .. } => q0 >= *m,
            Goal::JointPosition { max: Some(m), .. } => q0 <= *m,
            _ => false,
        };
        if already {
            self.fail(
                "goals",
                format!(
                    "the initial {} = {q0} already satisfies the inferred goal {}",
                    j.name,
                    goal.label()
                ),
            );
        }
        self.notes.inferred(
            "goals",
            format!(
                "'{}' → {} ({} beyond {} of the range)",
                steps.join("; "),
                goal.label(),
                if opening { "opened" } else { "closed" },
                if opening { "0.6" } else { "0.15" }
            ),
        );
        self.notes.inferred(
            "oracle",
            format!(
                "actuate {}.{} to {to} ({} of the range); the grasp substep is part of actuate",
                oid,
                j.name,
                if opening { "0.85" } else { "0.02" }
            ),
        );
        self.goals.push(goal);
        self.oracle.push(Primitive::Actuate {
            object: oid,
            joint: j.name.clone(),
            to,
        });
        self.articulate(k);
    }

    /// Object `k` made articulated: its frame is now the one at default joint positions (yaw
    /// is 0).
    fn articulate(&mut self, k: usize) {
        let o = &mut self.objs[k];
        if let Shape::Urdf { articulated, .. } = &mut o.object.shape {
            *articulated = true;
            let shift = o.frame_shift;
            if let Some(p) = &mut o.object.pose {
                for (c, d) in p.position.iter_mut().zip(shift) {
                    *c = r6(*c + d);
                }
            }
        }
    }

    /// "put/place the X into/in/on the Y": the first substep (past the grasps and releases of
    /// primitives) that names two of the objects so.
    fn placement_goal(&mut self, sub: &Substeps) {
        let mut done = false;
        for (s, kind) in sub.steps.iter().zip(sub.kinds.iter()) {
            let l = s.to_lowercase();
            if kind == "primitive" && (l.starts_with("grasp") || l.starts_with("release")) {
                continue;
            }
            let rel = [
                (" into the ", true),
                (" in the ", true),
                (" onto the ", false),
                (" on the ", false),
            ]
            .iter()
            .find_map(|(w, into)| {
                l.split_once(w)
                    .map(|(a, b)| (a.to_owned(), b.to_owned(), *into))
            });
            let Some((a, b, into)) = rel else { continue };
            let find = |t: &str| {
                self.objs
                    .iter()
                    .position(|o| t.contains(&o.name.to_lowercase()))
            };
            let (Some(oa), Some(ob)) = (find(&a), find(&b)) else {
                continue;
            };
            done = if into {
                self.place_into(s, oa, ob)
            } else {
                self.place_on(s, oa, ob)
            };
            break;
        }
        if !done && !self.fatal {
            self.fail(
                "substeps",
                format!(
                    "no goal can be inferred from the substeps '{}'",
                    sub.steps.join("; ")
                ),
            );
        }
    }

    /// Substep `s`: object `oa` into URDF object `ob`, at the bottom of its interior. Whether
    /// a goal came of it (else the error is noted).
    fn place_into(&mut self, s: &str, oa: usize, ob: usize) -> bool {
        let (ida, idb) = (self.objs[oa].id.clone(), self.objs[ob].id.clone());
        let Some((pos, place_xy)) = interior(&self.objs[ob]) else {
            let reason = format!(
                "'{s}': cannot find the interior of '{}'",
                self.objs[ob].name
            );
            self.fail("substeps", reason);
            return false;
        };
        self.goals.push(Goal::PoseWithin {
            object: ida.clone(),
            position: pos,
            tolerance: 0.14,
            yaw_deg: None,
            yaw_tolerance_deg: None,
            relative_to: None,
            planar: false,
            yaw_symmetry_deg: None,
        });
        self.oracle.push(Primitive::Pick {
            object: ida.clone(),
        });
        self.oracle.push(Primitive::Place {
            target: PlaceTarget::At(place_xy),
        });
        self.notes.inferred("goals", format!("'{s}' → pose_within({ida}) at the interior bottom centre of '{idb}' + 0.03 m, tolerance 0.14 (a URDF is no container, so in_container does not apply)"));
        self.notes.inferred("oracle", format!("pick {ida} (substep 'grasp'), place at {place_xy:?}: inside '{idb}', 0.06 m from its centre away from the lid; the floor stops the descent ('release' is the place's release)"));
        true
    }

    /// Substep `s`: object `oa` on top of object `ob`. Always a goal.
    fn place_on(&mut self, s: &str, oa: usize, ob: usize) -> bool {
        let (ida, idb) = (self.objs[oa].id.clone(), self.objs[ob].id.clone());
        self.goals.push(Goal::OnTopOf {
            object: ida.clone(),
            support: idb.clone(),
        });
        self.oracle.push(Primitive::Pick {
            object: ida.clone(),
        });
        self.oracle.push(Primitive::Place {
            target: PlaceTarget::On(idb.clone()),
        });
        self.notes
            .inferred("goals", format!("'{s}' → on_top_of({ida}, {idb})"));
        self.notes
            .inferred("oracle", format!("pick {ida}, place on {idb}"));
        true
    }
}

/// Bounds of some boxes, and each box's bounds.
type BoxesBounds = ([f64; 3], [f64; 3], Vec<([f64; 3], [f64; 3])>);

/// The interior bottom centre of a URDF box (world, + 0.03 m) and a release point 0.06 m from
/// it away from the moving parts (a lid), from the boxes of its visuals.
fn interior(o: &Obj) -> Option<([f64; 3], [f64; 2])> {
    let (_, u) = o.urdf.as_ref()?;
    let Shape::Urdf { joints, .. } = &o.object.shape else {
        return None;
    };
    let parts = u.placed_visuals(joints).ok()?;
    // Links that move: children of non-fixed joints and their descendants.
    let mut moving: BTreeSet<usize> = u
        .joints
        .iter()
        .filter(|j| j.kind != JointKind::Fixed)
        .map(|j| j.child)
        .collect();
    loop {
        let before = moving.len();
        for j in &u.joints {
            if moving.contains(&j.parent) {
                moving.insert(j.child);
            }
        }
        if moving.len() == before {
            break;
        }
    }
    let bbox = |sel: &dyn Fn(usize) -> bool| -> Option<BoxesBounds> {
        let (mut lo, mut hi) = ([f64::MAX; 3], [f64::MIN; 3]);
        let mut each = Vec::new();
        for p in parts.iter().filter(|p| sel(p.link)) {
            let Geometry::Box { size } = p.geometry else {
                continue;
            };
            let (mut plo, mut phi) = ([f64::MAX; 3], [f64::MIN; 3]);
            for c in 0..8 {
                let s = |b: usize| if c & (1 << b) == 0 { -0.5 } else { 0.5 };
                let q = p
                    .pose
                    .transform_point([s(0) * size[0], s(1) * size[1], s(2) * size[2]]);
                for k in 0..3 {
                    plo[k] = plo[k].min(q[k]);
                    phi[k] = phi[k].max(q[k]);
                }
            }
            for k in 0..3 {
                lo[k] = lo[k].min(plo[k]);
                hi[k] = hi[k].max(phi[k]);
            }
            each.push((plo, phi));
        }
        (lo[0] <= hi[0]).then_some((lo, hi, each))
    };
    let (alo, ahi, _) = bbox(&|_| true)?;
    let (blo, bhi, body) = bbox(&|l| !moving.contains(&l))?;
    let floor = body
        .iter()
        .filter(|(plo, _)| (plo[2] - blo[2]).abs() < 1e-3)
        .map(|(_, phi)| phi[2])
        .fold(f64::MAX, f64::min);
    let centre: [f64; 3] = std::array::from_fn(|k| (alo[k] + ahi[k]) / 2.0);
    let p = o.object.pose?.position;
    let world = |q: [f64; 3]| -> [f64; 3] { std::array::from_fn(|k| r6(p[k] + q[k] - centre[k])) };
    let bc = [(blo[0] + bhi[0]) / 2.0, (blo[1] + bhi[1]) / 2.0];
    let goal = world([bc[0], bc[1], floor + 0.03]);
    let mut dir = [1.0, 0.0];
    if let Some((llo, lhi, _)) = bbox(&|l| moving.contains(&l)) {
        let lc = [
            (llo[0] + lhi[0]) / 2.0 - bc[0],
            (llo[1] + lhi[1]) / 2.0 - bc[1],
        ];
        let n = (lc[0] * lc[0] + lc[1] * lc[1]).sqrt();
        if n > 1e-6 {
            dir = [-lc[0] / n, -lc[1] / n];
        }
    }
    Some((
        goal,
        [r3(goal[0] + 0.06 * dir[0]), r3(goal[1] + 0.06 * dir[1])],
    ))
}
