//! Seed 0's objects as the spec has them: a solid object (a URDF, or a container for GenSim's
//! bowl), a zone for a flat marker with nothing to collide, or a copy in a pile; and which
//! objects the code placed from another's pose. Never reads the goals' targets (`goals`).

use std::collections::BTreeMap;
use std::path::Path;

use super::{Kind, Made, TIED, Translation, rot_z, yaw_of};
use crate::gensim::EXTRA_COLORS;
use crate::gensim::sandbox::ObjectRecord;
use crate::r6;
use assay_spec::spec::{Color, Object, Pile, Pose, Region, Shape, Zone};

fn tilt_of(q: &[f64; 4]) -> f64 {
    let [x, y, z, w] = *q;
    let roll = (2.0 * (w * x + y * z)).atan2(1.0 - 2.0 * (x * x + y * y));
    let pitch = (2.0 * (w * y - z * x)).clamp(-1.0, 1.0).asin();
    roll.abs().max(pitch.abs())
}

/// The colour the task gave the object (`add_object(..., color=...)`, a template's colour, a
/// `changeVisualShape`), by name where it is one of the palette's; None where it gave none (the
/// URDF keeps its own materials, as in PyBullet).
fn color_of(o: &ObjectRecord) -> Option<Color> {
    if let Some(name) = &o.color_name {
        if let Some((_, rgb)) = EXTRA_COLORS.iter().find(|(k, _)| k == name) {
            return Some(Color::Rgb(*rgb));
        }
        if assay_spec::spec::COLORS.iter().any(|(k, _)| k == name) {
            return Some(Color::Named(name.clone()));
        }
    }
    o.color.map(|rgb| Color::Rgb(rgb.map(r6)))
}

pub(crate) fn fill_text(v: &serde_json::Value) -> Option<String> {
    match v {
        serde_json::Value::Number(n) => n.as_f64().map(|x| format!("{}", r6(x))),
        serde_json::Value::String(s) => Some(s.clone()),
        _ => None,
    }
}

/// The id an object's asset and colour name give it (`red_block`), before it is numbered.
fn base_name(o: &ObjectRecord) -> String {
    let stem = Path::new(&o.urdf)
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("object")
        .trim_end_matches("-template")
        .replace('-', "_");
    let stem = crate::slug(&stem, '_');
    match &o.color_name {
        Some(c) => format!("{}_{stem}", crate::slug(c, '_')),
        None => stem,
    }
}

/// Where seed 0 put a recorded object, and what its asset measures.
struct Placed {
    /// GenSim's base position.
    pos: [f64; 3],
    /// The centre of the asset's visual box from `pos`, in the world.
    c: [f64; 3],
    /// The visual box's half extents.
    half: [f64; 3],
    /// GenSim's yaw (rad).
    yaw: f64,
    /// The colour of the asset's base link (its first visual with a material): what PyBullet
    /// draws where the task gives none. A zone or a container, drawn in one colour, takes it.
    own: Option<[f64; 3]>,
}

impl Translation<'_> {
    /// Seed 0's objects, in order; `None` when one cannot be imported (the errors are noted).
    pub(super) fn objects(&mut self) -> Option<()> {
        let seeds = self.seeds;
        let mut counts: BTreeMap<String, usize> = BTreeMap::new();
        for (k, o) in seeds[0].objects.iter().enumerate() {
            let m = self.object(k, o, &mut counts);
            self.made.push(m);
        }
        if self.fatal {
            return None;
        }
        for p in &mut self.piles {
            p.region.min = p.region.min.map(|x| r6(x - 0.01));
            p.region.max = p.region.max.map(|x| r6(x + 0.01));
        }
        Some(())
    }

    /// Recorded object `k`, with `counts` the objects made so far of each base name; `None`
    /// when its asset cannot be read.
    fn object(
        &mut self,
        k: usize,
        o: &ObjectRecord,
        counts: &mut BTreeMap<String, usize>,
    ) -> Option<Made> {
        let field = format!("env.add_object[{k}]");
        if let Err(e) = crate::check_asset(self.asset_root, &o.urdf) {
            self.fail(&field, format!("URDF {e}"));
            return None;
        }
        let fill = self.fill(&field, o);
        let full = self.asset_root.join(&o.urdf);
        let assembled = match assay_spec::urdf::assemble_filled(
            &full,
            &fill,
            &BTreeMap::new(),
            &BTreeMap::new(),
        ) {
            Ok(a) => a,
            Err(e) => {
                self.fail(&field, format!("URDF '{}': {e}", o.urdf));
                return None;
            }
        };
        let (pos, rot) = o.pose;
        if tilt_of(&rot) > 1f64.to_radians() {
            self.notes.not_mapped(
                &format!("{field}.pose"),
                "a tilted pose (roll or pitch): spec v1 poses turn about z only; the object stands upright",
            );
        }
        let yaw = yaw_of(&rot);
        // The spec's frame is the centre of the visual box; GenSim's is the URDF's base link.
        let c = {
            let xy = rot_z(yaw, [assembled.centre[0], assembled.centre[1]]);
            [xy[0], xy[1], assembled.centre[2]]
        };
        let root = assembled.urdf.root();
        let own = assembled
            .visuals
            .iter()
            .filter(|(p, _)| p.link == root)
            .find_map(|(p, _)| p.color)
            .map(|c| [c[0], c[1], c[2]].map(|x| r6(f64::from(x))));
        let placed = Placed {
            pos,
            c,
            half: assembled.half,
            yaw,
            own,
        };
        let base = base_name(o);
        let marker = assembled.urdf.links.iter().all(|l| l.collisions.is_empty());
        if o.pile {
            return Some(self.pile_copy(o, &base, fill, &placed));
        }
        let n = counts.entry(base.clone()).or_insert(0);
        let id = if *n == 0 {
            base.clone()
        } else {
            format!("{base}_{n}")
        };
        *n += 1;
        if marker {
            return Some(self.zone(&field, id, o, &placed));
        }
        let reach = assembled.collision_half();
        Some(self.solid(&field, id, o, fill, &placed, reach))
    }

    /// The template values `o` fills in (an error for a value that is neither a number nor a
    /// file name).
    fn fill(&mut self, field: &str, o: &ObjectRecord) -> BTreeMap<String, String> {
        let mut fill = BTreeMap::new();
        for (key, v) in &o.fill {
            match fill_text(v) {
                Some(t) => {
                    fill.insert(key.clone(), t);
                }
                None => {
                    self.fail(
                        &format!("{field}.fill.{key}"),
                        format!("not a number or a file name: {v}"),
                    );
                }
            }
        }
        fill
    }

    /// A copy in the pile of `base`: the pile is made with the first, its region grows with
    /// each.
    fn pile_copy(
        &mut self,
        o: &ObjectRecord,
        base: &str,
        fill: BTreeMap<String, String>,
        placed: &Placed,
    ) -> Made {
        let pos = placed.pos;
        let pid = format!("{base}_pile");
        if let Some(p) = self.piles.iter_mut().find(|p| p.id == pid) {
            p.count += 1;
            p.region.min = [p.region.min[0].min(pos[0]), p.region.min[1].min(pos[1])];
            p.region.max = [p.region.max[0].max(pos[0]), p.region.max[1].max(pos[1])];
        } else {
            self.piles.push(Pile {
                id: pid.clone(),
                count: 1,
                shape: Shape::Urdf {
                    path: o.urdf.clone(),
                    joints: BTreeMap::new(),
                    articulated: false,
                    fill,
                },
                color: color_of(o),
                mass: None,
                region: Region {
                    min: [pos[0], pos[1]],
                    max: [pos[0], pos[1]],
                },
            });
        }
        Made {
            id: pid,
            kind: Kind::Pile,
            shift: [0.0; 3],
            yaw: placed.yaw,
            moved: false,
        }
    }

    /// A flat marker with nothing to collide (a zone, a line): drawn, not simulated.
    fn zone(&mut self, field: &str, id: String, o: &ObjectRecord, placed: &Placed) -> Made {
        let Placed {
            pos, c, half, yaw, ..
        } = *placed;
        self.zones.push(Zone {
            id: id.clone(),
            center: [r6(pos[0] + c[0]), r6(pos[1] + c[1])],
            half_extents: [r6(half[0].max(0.005)), r6(half[1].max(0.005))],
            // No colour from the task: the asset's own (GenSim's zone.urdf is green).
            color: color_of(o)
                .or(placed.own.map(Color::Rgb))
                .unwrap_or_default(),
        });
        self.notes.mapped(
            field,
            format!(
                "zone '{id}' from '{}' (visual only: a flat marker, axis-aligned in spec v1)",
                o.urdf
            ),
        );
        Made {
            id,
            kind: Kind::Zone,
            shift: [c[0], c[1], 0.0],
            yaw,
            moved: false,
        }
    }

    /// An object that collides (GenSim's bowl becomes a container), standing on the table at
    /// least; `reach`: the half extents of its collision shapes.
    fn solid(
        &mut self,
        field: &str,
        id: String,
        o: &ObjectRecord,
        fill: BTreeMap<String, String>,
        placed: &Placed,
        reach: [f64; 3],
    ) -> Made {
        let Placed {
            pos, c, half, yaw, ..
        } = *placed;
        let container = o.urdf.ends_with("bowl/bowl.urdf");
        let shape = if container {
            Shape::Container {
                inner_half_extents: [0.05, 0.05, 0.015],
                wall: 0.01,
            }
        } else {
            Shape::Urdf {
                path: o.urdf.clone(),
                joints: BTreeMap::new(),
                articulated: false,
                fill: fill.clone(),
            }
        };
        let half_z = if container { 0.02 } else { half[2] };
        let centre = [pos[0] + c[0], pos[1] + c[1], (pos[2] + c[2]).max(half_z)];
        self.notes.mapped(
            field,
            if fill.is_empty() {
                format!("object '{id}' from '{}'", o.urdf)
            } else {
                format!(
                    "object '{id}' from template '{}' filled with {:?}",
                    o.urdf, fill
                )
            },
        );
        // What it occupies: its visual box, or its collision shapes where they reach further.
        self.halves.insert(
            id.clone(),
            [half[0].max(reach[0]), half[1].max(reach[1]), half_z],
        );
        self.objects.push(Object {
            id: id.clone(),
            shape,
            // A container is drawn in one colour: the asset's own where the task gave none
            // (GenSim's bowl.urdf is green); a URDF keeps its materials itself.
            color: if container {
                color_of(o).or(placed.own.map(Color::Rgb))
            } else {
                color_of(o)
            },
            mass: None,
            is_fixed: o.category == "fixed",
            pose: Some(Pose {
                position: centre.map(r6),
                yaw_deg: r6(yaw.to_degrees()),
            }),
            pose_range: None,
        });
        Made {
            id,
            kind: Kind::Object { container },
            shift: [c[0], c[1], centre[2] - pos[2]],
            yaw,
            moved: false,
        }
    }

    /// Objects placed from another's pose (a part on a base, a block in a bowl) keep their
    /// relation only when nothing moves them apart: such pairs, and no position jitter when
    /// two of them stand close.
    pub(super) fn tied_objects(&mut self) {
        let same = &self.same;
        for (k, m) in self.made.iter().enumerate() {
            let Some(m) = m else { continue };
            if !matches!(m.kind, Kind::Object { .. }) || same.len() < 2 {
                continue;
            }
            for (q, other) in self.made.iter().enumerate() {
                let Some(other) = other else { continue };
                if q == k || !matches!(other.kind, Kind::Object { .. }) {
                    continue;
                }
                let d: Vec<[f64; 3]> = same
                    .iter()
                    .map(|s| {
                        let (a, b) = (&s.objects[k].pose.0, &s.objects[q].pose.0);
                        [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
                    })
                    .collect();
                let tied = d
                    .windows(2)
                    .all(|w| (0..3).all(|a| (w[0][a] - w[1][a]).abs() <= TIED));
                if tied {
                    self.tied_pairs.insert((m.id.clone(), other.id.clone()));
                }
                if tied && d[0][0].hypot(d[0][1]) < 0.2 && self.jitter > 0.0 {
                    self.jitter = 0.0;
                    self.notes.inferred(
                        "variations.position_jitter",
                        format!(
                            "0: '{}' is placed from the pose of '{}', and independent jitter would move them apart",
                            m.id, other.id
                        ),
                    );
                }
            }
        }
    }

    /// The objects a goal of seed 0 moves.
    pub(super) fn mark_moved(&mut self) {
        let seeds = self.seeds;
        for g in &seeds[0].goals {
            for &oid in &g.objs {
                if let Some(Some(m)) = self.made.get_mut(oid.wrapping_sub(1)) {
                    m.moved = true;
                }
            }
        }
    }
}
