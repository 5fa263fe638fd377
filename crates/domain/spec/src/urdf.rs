//! Articulated objects from URDF: the link tree, its joints and its visual and collision shapes,
//! forward kinematics, and the mesh files shapes refer to (OBJ and STL).
//!
//! Lengths are metres and angles radians, as in URDF. Only kinematic trees whose joints are
//! fixed, revolute, continuous or prismatic are read; inertials, dynamics and transmissions are
//! ignored. Every error names the link, joint or element it is about and why.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use roxmltree::Node;

use crate::scene::{TriangleMesh, parse_obj};

/// A robot or articulated object: its links, and the joints that connect them into one tree.
#[derive(Debug, Clone, PartialEq)]
pub struct Urdf {
    pub name: String,
    pub links: Vec<Link>,
    pub joints: Vec<Joint>,
    root: usize,
    /// Joint indices, each parent link's joint before its children's.
    order: Vec<usize>,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Link {
    pub name: String,
    pub visuals: Vec<Part>,
    pub collisions: Vec<Part>,
    /// Bullet's `<contact><rolling_friction value=".."/>` (m): the most rolling torque a contact
    /// resists, per newton of normal force; 0 where the link declares none.
    pub rolling_friction: f64,
}

/// One visual or collision shape of a link, placed in the link's frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Part {
    pub origin: Origin,
    pub geometry: Geometry,
    /// RGBA of a visual's material (inline or named at robot level); collisions have none.
    pub color: Option<[f32; 4]>,
}

/// A frame relative to its parent: translation, then fixed-axis roll (X), pitch (Y), yaw (Z),
/// i.e. R = Rz(yaw) · Ry(pitch) · Rx(roll).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Origin {
    pub xyz: [f64; 3],
    pub rpy: [f64; 3],
}

#[derive(Debug, Clone, PartialEq)]
pub enum Geometry {
    /// Full edge lengths, centred on the origin.
    Box {
        size: [f64; 3],
    },
    /// Along local Z, centred on the origin.
    Cylinder {
        radius: f64,
        length: f64,
    },
    Sphere {
        radius: f64,
    },
    /// `filename` as written (see [`resolve_mesh`]); `scale` applies per axis.
    Mesh {
        filename: String,
        scale: [f64; 3],
    },
}

#[derive(Debug, Clone, PartialEq)]
pub struct Joint {
    pub name: String,
    pub kind: JointKind,
    /// Index into [`Urdf::links`].
    pub parent: usize,
    pub child: usize,
    /// The joint frame in the parent link's frame; the child link's frame is the joint frame moved.
    pub origin: Origin,
    /// Unit vector in the joint frame; defaults to +X.
    pub axis: [f64; 3],
    /// (lower, upper) in radians or metres; present for revolute and prismatic joints only.
    pub limit: Option<[f64; 2]>,
    /// `<dynamics friction>`: the force (N) or torque (N m) the joint resists motion with.
    pub friction: f64,
    /// `<dynamics damping>`: resistance proportional to velocity (N s/m or N m s/rad).
    pub damping: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JointKind {
    Fixed,
    Revolute,
    Continuous,
    Prismatic,
}

/// How far (rad or m) a joint position may lie outside its limits and be taken as at them: a
/// simulated joint passes its limit by a hair, and a position recorded in single precision
/// rounds across it.
pub const LIMIT_SLACK: f64 = 1e-5;

/// A rigid transform: rotate by the unit quaternion `rotation` (x, y, z, w), then translate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    pub translation: [f64; 3],
    pub rotation: [f64; 4],
}

/// A link's shape placed in the root link's frame.
#[derive(Debug, Clone, PartialEq)]
pub struct PlacedPart {
    /// Index into [`Urdf::links`].
    pub link: usize,
    pub pose: Pose,
    pub geometry: Geometry,
    pub color: Option<[f32; 4]>,
}

fn quat_mul(a: [f64; 4], b: [f64; 4]) -> [f64; 4] {
    let [ax, ay, az, aw] = a;
    let [bx, by, bz, bw] = b;
    [
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ]
}

/// Rotation by `angle` about the unit vector `axis`.
fn quat_axis_angle(axis: [f64; 3], angle: f64) -> [f64; 4] {
    let (s, c) = (angle / 2.0).sin_cos();
    [axis[0] * s, axis[1] * s, axis[2] * s, c]
}

/// The quaternion (x, y, z, w) of URDF's `rpy`: Rz(yaw) · Ry(pitch) · Rx(roll).
pub fn quat_from_rpy(rpy: [f64; 3]) -> [f64; 4] {
    let z = quat_axis_angle([0.0, 0.0, 1.0], rpy[2]);
    let y = quat_axis_angle([0.0, 1.0, 0.0], rpy[1]);
    let x = quat_axis_angle([1.0, 0.0, 0.0], rpy[0]);
    quat_mul(quat_mul(z, y), x)
}

impl Pose {
    pub const IDENTITY: Pose = Pose {
        translation: [0.0; 3],
        rotation: [0.0, 0.0, 0.0, 1.0],
    };

    pub fn from_origin(origin: &Origin) -> Pose {
        Pose {
            translation: origin.xyz,
            rotation: quat_from_rpy(origin.rpy),
        }
    }

    /// `self ∘ other`: `other` is given in `self`'s frame.
    pub fn compose(&self, other: &Pose) -> Pose {
        let t = self.rotate(other.translation);
        let q = quat_mul(self.rotation, other.rotation);
        let n = q.iter().map(|c| c * c).sum::<f64>().sqrt();
        Pose {
            translation: [0, 1, 2].map(|i| self.translation[i] + t[i]),
            rotation: q.map(|c| c / n),
        }
    }

    /// `v` rotated (not translated).
    pub fn rotate(&self, v: [f64; 3]) -> [f64; 3] {
        let [x, y, z, w] = self.rotation;
        let cross = |a: [f64; 3], b: [f64; 3]| {
            [
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ]
        };
        let u = [x, y, z];
        let uv = cross(u, v);
        let uuv = cross(u, uv);
        [0, 1, 2].map(|i| v[i] + 2.0 * (w * uv[i] + uuv[i]))
    }

    /// The point `p` moved by this pose.
    pub fn transform_point(&self, p: [f64; 3]) -> [f64; 3] {
        let r = self.rotate(p);
        [0, 1, 2].map(|i| r[i] + self.translation[i])
    }
}

impl Joint {
    /// The position used when none is given: 0, or the lower limit if 0 lies outside the limits.
    pub fn default_position(&self) -> f64 {
        match self.limit {
            Some([lo, hi]) if !(lo..=hi).contains(&0.0) => lo,
            _ => 0.0,
        }
    }

    /// The child link's frame in the parent link's frame at position `q`: origin ∘ motion.
    pub fn transform(&self, q: f64) -> Pose {
        let motion = match self.kind {
            JointKind::Fixed => Pose::IDENTITY,
            JointKind::Revolute | JointKind::Continuous => Pose {
                translation: [0.0; 3],
                rotation: quat_axis_angle(self.axis, q),
            },
            JointKind::Prismatic => Pose {
                translation: self.axis.map(|a| a * q),
                rotation: Pose::IDENTITY.rotation,
            },
        };
        Pose::from_origin(&self.origin).compose(&motion)
    }
}

impl Urdf {
    /// Index of the root link (the one that is no joint's child).
    pub fn root(&self) -> usize {
        self.root
    }

    /// Joint indices, each parent link's joint before its children's.
    pub fn joint_order(&self) -> &[usize] {
        &self.order
    }

    /// Pose of every link (in `links` order) in the root link's frame. `positions` maps movable
    /// joint names to positions; joints left out are at [`Joint::default_position`].
    pub fn link_poses(&self, positions: &BTreeMap<String, f64>) -> Result<Vec<Pose>, String> {
        for (name, &q) in positions {
            let joint = self
                .joints
                .iter()
                .find(|j| j.name == *name && j.kind != JointKind::Fixed)
                .ok_or_else(|| format!("positions: '{name}' is not a movable joint"))?;
            if !q.is_finite() {
                return Err(format!("joint '{name}': position {q} is not finite"));
            }
            if let Some([lo, hi]) = joint.limit
                && !(lo - LIMIT_SLACK..=hi + LIMIT_SLACK).contains(&q)
            {
                return Err(format!(
                    "joint '{name}': position {q} is outside its limits [{lo}, {hi}]"
                ));
            }
        }
        let mut poses = vec![Pose::IDENTITY; self.links.len()];
        for &j in &self.order {
            let joint = &self.joints[j];
            let q = positions
                .get(&joint.name)
                .copied()
                .unwrap_or_else(|| joint.default_position());
            let q = match joint.limit {
                Some([lo, hi]) => q.clamp(lo, hi),
                None => q,
            };
            poses[joint.child] = poses[joint.parent].compose(&joint.transform(q));
        }
        Ok(poses)
    }

    /// Every link's visuals, placed in the root frame.
    pub fn placed_visuals(
        &self,
        positions: &BTreeMap<String, f64>,
    ) -> Result<Vec<PlacedPart>, String> {
        self.place(positions, |l| &l.visuals)
    }

    /// Every link's collision shapes, or its visuals (with their colours) where it has none.
    pub fn placed_collisions(
        &self,
        positions: &BTreeMap<String, f64>,
    ) -> Result<Vec<PlacedPart>, String> {
        self.place(positions, |l| {
            if l.collisions.is_empty() {
                &l.visuals
            } else {
                &l.collisions
            }
        })
    }

    fn place<'a>(
        &'a self,
        positions: &BTreeMap<String, f64>,
        parts: impl Fn(&'a Link) -> &'a [Part],
    ) -> Result<Vec<PlacedPart>, String> {
        let poses = self.link_poses(positions)?;
        let mut placed = Vec::new();
        for (i, (link, pose)) in self.links.iter().zip(&poses).enumerate() {
            placed.extend(parts(link).iter().map(|p| PlacedPart {
                link: i,
                pose: pose.compose(&Pose::from_origin(&p.origin)),
                geometry: p.geometry.clone(),
                color: p.color,
            }));
        }
        Ok(placed)
    }
}

fn elements<'a, 'i>(n: Node<'a, 'i>, tag: &str) -> impl Iterator<Item = Node<'a, 'i>> {
    n.children().filter(move |c| c.has_tag_name(tag))
}

fn element<'a, 'i>(n: Node<'a, 'i>, tag: &str) -> Option<Node<'a, 'i>> {
    elements(n, tag).next()
}

fn attr<'a>(n: Node<'a, '_>, key: &str) -> Result<&'a str, String> {
    n.attribute(key)
        .ok_or_else(|| format!("missing attribute '{key}'"))
}

/// `N` finite numbers from attribute `key`, or `default` when it is absent.
fn numbers<const N: usize>(
    n: Node<'_, '_>,
    key: &str,
    default: Option<[f64; N]>,
) -> Result<[f64; N], String> {
    let Some(s) = n.attribute(key) else {
        return default.ok_or_else(|| format!("missing attribute '{key}'"));
    };
    let bad = |why: &str| format!("{key} \"{s}\": {why}");
    let expected = if N == 1 {
        "expected a number".to_owned()
    } else {
        format!("expected {N} numbers")
    };
    let v: Vec<f64> = s
        .split_whitespace()
        .map(str::parse)
        .collect::<Result<_, _>>()
        .map_err(|_| bad(&expected))?;
    let v: [f64; N] = v.try_into().map_err(|_| bad(&expected))?;
    if v.iter().any(|x| !x.is_finite()) {
        return Err(bad("numbers must be finite"));
    }
    Ok(v)
}

/// Required non-negative sizes.
fn sizes<const N: usize>(n: Node<'_, '_>, key: &str) -> Result<[f64; N], String> {
    let v = numbers::<N>(n, key, None)?;
    if v.iter().any(|x| *x < 0.0) {
        return Err(format!("{key} \"{}\": must not be negative", attr(n, key)?));
    }
    Ok(v)
}

fn origin(n: Node<'_, '_>) -> Result<Origin, String> {
    let Some(o) = element(n, "origin") else {
        return Ok(Origin::default());
    };
    let f = |key| numbers(o, key, Some([0.0; 3])).map_err(|e| format!("origin: {e}"));
    Ok(Origin {
        xyz: f("xyz")?,
        rpy: f("rpy")?,
    })
}

fn geometry(n: Node<'_, '_>) -> Result<Geometry, String> {
    let g = element(n, "geometry").ok_or("missing <geometry>")?;
    let shape = g
        .children()
        .find(Node::is_element)
        .ok_or("geometry: no shape in <geometry>")?;
    let tag = shape.tag_name().name();
    let ctx = |e: String| format!("geometry: {tag} {e}");
    Ok(match tag {
        "box" => Geometry::Box {
            size: sizes(shape, "size").map_err(ctx)?,
        },
        "cylinder" => Geometry::Cylinder {
            radius: sizes::<1>(shape, "radius").map_err(ctx)?[0],
            length: sizes::<1>(shape, "length").map_err(ctx)?[0],
        },
        "sphere" => Geometry::Sphere {
            radius: sizes::<1>(shape, "radius").map_err(ctx)?[0],
        },
        "mesh" => Geometry::Mesh {
            filename: attr(shape, "filename").map_err(ctx)?.to_owned(),
            scale: numbers(shape, "scale", Some([1.0; 3])).map_err(ctx)?,
        },
        other => return Err(format!("geometry: unknown shape <{other}>")),
    })
}

type Materials = BTreeMap<String, Option<[f32; 4]>>;

/// The colour of a `<material>`: its own `<color>`, or the named robot-level material's. A named
/// material with a colour is remembered for later references, as urdfdom does.
fn material(m: Node<'_, '_>, materials: &mut Materials) -> Result<Option<[f32; 4]>, String> {
    let name = m.attribute("name");
    let ctx = |e: String| match name {
        Some(name) => format!("material '{name}': {e}"),
        None => format!("material: {e}"),
    };
    if let Some(c) = element(m, "color") {
        let rgba = numbers::<4>(c, "rgba", None).map_err(|e| ctx(format!("color {e}")))?;
        if rgba.iter().any(|x| !(0.0..=1.0).contains(x)) {
            return Err(ctx(format!(
                "color rgba {rgba:?}: components must lie in [0, 1]"
            )));
        }
        let rgba = rgba.map(|x| x as f32);
        if let Some(name) = name {
            materials.entry(name.to_owned()).or_insert(Some(rgba));
        }
        return Ok(Some(rgba));
    }
    if let Some(color) = name.and_then(|n| materials.get(n)) {
        return Ok(*color);
    }
    if element(m, "texture").is_some() {
        return Ok(None);
    }
    Err(ctx("no <color> here and not defined at robot level".into()))
}

/// A visual (with `materials`) or collision shape.
fn part(n: Node<'_, '_>, materials: Option<&mut Materials>) -> Result<Part, String> {
    let color = match (element(n, "material"), materials) {
        (Some(m), Some(materials)) => material(m, materials)?,
        _ => None,
    };
    Ok(Part {
        origin: origin(n)?,
        geometry: geometry(n)?,
        color,
    })
}

fn link(name: &str, n: Node<'_, '_>, materials: &mut Materials) -> Result<Link, String> {
    let rolling_friction = match element(n, "contact").and_then(|c| element(c, "rolling_friction"))
    {
        Some(r) => {
            let v: f64 = attr(r, "value")?
                .trim()
                .parse()
                .map_err(|_| "contact/rolling_friction: value is not a number".to_owned())?;
            if !v.is_finite() || v < 0.0 {
                return Err(format!(
                    "contact/rolling_friction: {v} is not a finite length of 0 or more"
                ));
            }
            v
        }
        None => 0.0,
    };
    let mut link = Link {
        name: name.to_owned(),
        visuals: Vec::new(),
        collisions: Vec::new(),
        rolling_friction,
    };
    for (i, v) in elements(n, "visual").enumerate() {
        let visual = part(v, Some(materials)).map_err(|e| format!("visual {i}: {e}"))?;
        link.visuals.push(visual);
    }
    for (i, c) in elements(n, "collision").enumerate() {
        let collision = part(c, None).map_err(|e| format!("collision {i}: {e}"))?;
        link.collisions.push(collision);
    }
    Ok(link)
}

fn joint(name: &str, n: Node<'_, '_>, links: &[Link]) -> Result<Joint, String> {
    let kind_name = attr(n, "type")?;
    let kind = match kind_name {
        "fixed" => JointKind::Fixed,
        "revolute" => JointKind::Revolute,
        "continuous" => JointKind::Continuous,
        "prismatic" => JointKind::Prismatic,
        "floating" | "planar" => {
            return Err(format!("type '{kind_name}' is not supported"));
        }
        other => return Err(format!("unknown type '{other}'")),
    };
    let end = |tag: &str| {
        let e = element(n, tag).ok_or_else(|| format!("missing <{tag}>"))?;
        let name = attr(e, "link").map_err(|e| format!("{tag}: {e}"))?;
        links
            .iter()
            .position(|l| l.name == name)
            .ok_or_else(|| format!("unknown {tag} link '{name}'"))
    };
    let (parent, child) = (end("parent")?, end("child")?);
    let axis = match element(n, "axis") {
        Some(a) => {
            let v = numbers(a, "xyz", Some([1.0, 0.0, 0.0])).map_err(|e| format!("axis {e}"))?;
            let len = v.iter().map(|c| c * c).sum::<f64>().sqrt();
            if len < 1e-12 {
                return Err(format!("axis xyz {v:?}: zero length"));
            }
            v.map(|c| c / len)
        }
        None => [1.0, 0.0, 0.0],
    };
    let limit = match kind {
        JointKind::Revolute | JointKind::Prismatic => {
            let l = element(n, "limit")
                .ok_or_else(|| format!("missing <limit> (required for {kind_name} joints)"))?;
            let bound = |key| numbers::<1>(l, key, Some([0.0])).map_err(|e| format!("limit: {e}"));
            let [lo, hi] = [bound("lower")?[0], bound("upper")?[0]];
            if lo > hi {
                return Err(format!("limit: lower {lo} is above upper {hi}"));
            }
            Some([lo, hi])
        }
        JointKind::Fixed | JointKind::Continuous => None,
    };
    let (friction, damping) = match element(n, "dynamics") {
        Some(d) => {
            let value = |key| -> Result<f64, String> {
                let x = numbers::<1>(d, key, Some([0.0])).map_err(|e| format!("dynamics {e}"))?[0];
                if x < 0.0 {
                    return Err(format!("dynamics {key} {x}: must not be negative"));
                }
                Ok(x)
            };
            (value("friction")?, value("damping")?)
        }
        None => (0.0, 0.0),
    };
    Ok(Joint {
        name: name.to_owned(),
        kind,
        parent,
        child,
        origin: origin(n)?,
        axis,
        limit,
        friction,
        damping,
    })
}

/// Reads a URDF document: a `<robot>` whose links form one tree.
pub fn parse(text: &str) -> Result<Urdf, String> {
    let doc = roxmltree::Document::parse(text).map_err(|e| format!("XML: {e}"))?;
    let robot = doc.root_element();
    if !robot.has_tag_name("robot") {
        return Err(format!(
            "root element is <{}>, not <robot>",
            robot.tag_name().name()
        ));
    }
    let name = attr(robot, "name")
        .map_err(|e| format!("robot: {e}"))?
        .to_owned();
    let mut materials = Materials::new();
    for m in elements(robot, "material") {
        let name = attr(m, "name").map_err(|e| format!("material: {e}"))?;
        if materials.contains_key(name) {
            return Err(format!("duplicate material '{name}'"));
        }
        let color = material(m, &mut materials)?;
        materials.insert(name.to_owned(), color);
    }
    let mut links: Vec<Link> = Vec::new();
    for (i, n) in elements(robot, "link").enumerate() {
        let name = attr(n, "name").map_err(|e| format!("link {i}: {e}"))?;
        if links.iter().any(|l| l.name == name) {
            return Err(format!("duplicate link '{name}'"));
        }
        links.push(link(name, n, &mut materials).map_err(|e| format!("link '{name}': {e}"))?);
    }
    let mut joints: Vec<Joint> = Vec::new();
    for (i, n) in elements(robot, "joint").enumerate() {
        let name = attr(n, "name").map_err(|e| format!("joint {i}: {e}"))?;
        if joints.iter().any(|j| j.name == name) {
            return Err(format!("duplicate joint '{name}'"));
        }
        joints.push(joint(name, n, &links).map_err(|e| format!("joint '{name}': {e}"))?);
    }

    // The joints must make the links one tree: one parent per link, one root, no cycle.
    if links.is_empty() {
        return Err("robot has no links".into());
    }
    let mut parent_joint: Vec<Option<usize>> = vec![None; links.len()];
    for (j, joint) in joints.iter().enumerate() {
        if let Some(other) = parent_joint[joint.child].replace(j) {
            return Err(format!(
                "link '{}' has two parent joints ('{}' and '{}')",
                links[joint.child].name, joints[other].name, joint.name
            ));
        }
    }
    let roots: Vec<usize> = (0..links.len())
        .filter(|&l| parent_joint[l].is_none())
        .collect();
    let root = match roots[..] {
        [root] => root,
        [] => return Err("no root link: the joints form a cycle".into()),
        _ => {
            let names: Vec<&str> = roots.iter().map(|&l| links[l].name.as_str()).collect();
            return Err(format!(
                "several root links ({}): joints must connect all links into one tree",
                names.join(", ")
            ));
        }
    };
    let mut order = Vec::new();
    let mut stack = vec![root];
    while let Some(l) = stack.pop() {
        for (j, joint) in joints.iter().enumerate().filter(|(_, jt)| jt.parent == l) {
            order.push(j);
            stack.push(joint.child);
        }
    }
    if let Some(j) = (0..joints.len()).find(|j| !order.contains(j)) {
        return Err(format!(
            "joint '{}': part of a cycle of joints not connected to the root link '{}'",
            joints[j].name, links[root].name
        ));
    }
    Ok(Urdf {
        name,
        links,
        joints,
        root,
        order,
    })
}

/// The file a mesh `filename` names: `package://<pkg>/rest` is looked for at `urdf_dir/rest`,
/// `urdf_dir/../rest` and `asset_root/<pkg>/rest` (the first that exists); `file://path` and
/// plain paths are relative to `urdf_dir` unless absolute. The file must lie inside `asset_root`.
pub fn resolve_mesh(filename: &str, urdf_dir: &Path, asset_root: &Path) -> Result<PathBuf, String> {
    let candidates = if let Some(rest) = filename.strip_prefix("package://") {
        let (pkg, rest) = rest
            .split_once('/')
            .ok_or_else(|| format!("mesh '{filename}': expected package://<package>/<path>"))?;
        vec![
            urdf_dir.join(rest),
            urdf_dir.join("..").join(rest),
            asset_root.join(pkg).join(rest),
        ]
    } else if let Some(path) = filename.strip_prefix("file://") {
        vec![urdf_dir.join(path)]
    } else if filename.contains("://") {
        return Err(format!("mesh '{filename}': unsupported URL scheme"));
    } else {
        vec![urdf_dir.join(filename)]
    };
    let Some(found) = candidates.iter().find(|p| p.exists()) else {
        let tried: Vec<String> = candidates.iter().map(|p| p.display().to_string()).collect();
        return Err(format!(
            "mesh '{filename}': not found (tried {})",
            tried.join(", ")
        ));
    };
    let canonical = |p: &Path| {
        p.canonicalize()
            .map_err(|e| format!("{}: {e}", p.display()))
    };
    let (path, root) = (canonical(found)?, canonical(asset_root)?);
    if !path.starts_with(&root) {
        return Err(format!(
            "mesh '{filename}': {} escapes the asset root {}",
            path.display(),
            root.display()
        ));
    }
    Ok(path)
}

/// Reads an `.obj` or `.stl` mesh file.
pub fn load_mesh(path: &Path) -> Result<TriangleMesh, String> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    let at = |e: String| format!("{}: {e}", path.display());
    match ext.as_str() {
        "obj" => parse_obj(&crate::assets::read_to_string(path).map_err(at)?).map_err(at),
        "stl" => parse_stl(&crate::assets::read(path).map_err(at)?).map_err(at),
        _ => Err(at(format!(
            "unsupported mesh format '{ext}' (convert to OBJ or STL)"
        ))),
    }
}

/// Reads binary or ASCII STL with `stl_io`; every triangle gets its own three vertices.
///
/// Whether a file is binary is decided here, not by `stl_io` (which calls anything starting
/// with `solid ` ASCII): a file is binary when its length is exactly 84 + 50 × the triangle
/// count in its header, as exporters that start binary headers with "solid" are common. Such a
/// header is blanked before reading (it carries no geometry), and an ASCII file's unnamed
/// `solid` line is given a name, so `stl_io` reads each as what it is.
pub fn parse_stl(bytes: &[u8]) -> Result<TriangleMesh, String> {
    let binary = bytes.get(80..84).is_some_and(|c| {
        84 + 50 * u64::from(u32::from_le_bytes([c[0], c[1], c[2], c[3]])) == bytes.len() as u64
    });
    let input: Vec<u8> = if binary {
        let mut b = bytes.to_vec();
        b[..80].fill(0);
        b
    } else {
        let not_stl =
            "neither binary STL (its length does not match its triangle count) nor ASCII STL";
        let text = std::str::from_utf8(bytes)
            .map_err(|_| not_stl)?
            .trim_start();
        let Some(rest) = text.strip_prefix("solid") else {
            return Err(not_stl.into());
        };
        match rest.chars().next() {
            Some(' ') => text.as_bytes().to_vec(),
            Some('\r' | '\n') | None => format!("solid unnamed{rest}").into_bytes(),
            Some(_) => return Err(not_stl.into()),
        }
    };
    let mut cursor = std::io::Cursor::new(input);
    let reader = stl_io::create_stl_reader(&mut cursor).map_err(|e| format!("STL: {e}"))?;
    let mut vertices: Vec<[f32; 3]> = Vec::new();
    for triangle in reader {
        let triangle = triangle.map_err(|e| format!("STL: {e}"))?;
        vertices.extend(triangle.vertices.map(|v| v.0));
    }
    if vertices.is_empty() {
        return Err("no triangles".into());
    }
    if vertices.iter().flatten().any(|c| !c.is_finite()) {
        return Err("non-finite vertex coordinates".into());
    }
    let triangles = (0..vertices.len() as u32 / 3)
        .map(|t| [3 * t, 3 * t + 1, 3 * t + 2])
        .collect();
    Ok(TriangleMesh {
        vertices,
        triangles,
    })
}

/// A URDF object posed rigidly at given joint positions, ready to draw and collide: its parts
/// in the object's frame, which is the centre of the visual parts' bounding box (as every other
/// shape's frame is its centre), with mesh files loaded.
#[derive(Debug, Clone, PartialEq)]
pub struct Assembled {
    /// Visual parts, with the mesh of each mesh part.
    pub visuals: Vec<(PlacedPart, Option<TriangleMesh>)>,
    /// Collision parts (a link's visuals where it has none), with their meshes.
    pub collisions: Vec<(PlacedPart, Option<TriangleMesh>)>,
    /// Half extents of the visual parts' bounding box.
    pub half: [f64; 3],
    /// The object's frame (the centre of that box) in the root link's frame: a part's pose in
    /// the object frame is its pose in the root frame moved by `-centre`.
    pub centre: [f64; 3],
    /// The URDF as read.
    pub urdf: Urdf,
}

impl Assembled {
    /// Half extents, about the object's frame, of the box that holds its collision parts. They
    /// may reach past the visual box `half` (Ravens' cylinder template swaps radius and length
    /// between its visual and its collision).
    pub fn collision_half(&self) -> [f64; 3] {
        let mut h = [0.0f64; 3];
        for (p, m) in &self.collisions {
            for c in part_corners(p, m.as_ref()) {
                for k in 0..3 {
                    h[k] = h[k].max(c[k].abs());
                }
            }
        }
        h
    }
}

/// Points bounding a part placed by `pose` (corners of its box, or its mesh's vertices).
fn part_corners(part: &PlacedPart, mesh: Option<&TriangleMesh>) -> Vec<[f64; 3]> {
    let boxed = |h: [f64; 3]| -> Vec<[f64; 3]> {
        (0..8)
            .map(|k| {
                let s = |b: usize| if k & (1 << b) == 0 { -1.0 } else { 1.0 };
                part.pose
                    .transform_point([s(0) * h[0], s(1) * h[1], s(2) * h[2]])
            })
            .collect()
    };
    match &part.geometry {
        Geometry::Box { size } => boxed(size.map(|x| x / 2.0)),
        Geometry::Sphere { radius } => boxed([*radius; 3]),
        Geometry::Cylinder { radius, length } => boxed([*radius, *radius, length / 2.0]),
        Geometry::Mesh { scale, .. } => mesh
            .map(|m| {
                m.vertices
                    .iter()
                    .map(|v| {
                        part.pose
                            .transform_point(std::array::from_fn(|k| f64::from(v[k]) * scale[k]))
                    })
                    .collect()
            })
            .unwrap_or_default(),
    }
}

/// Reads the URDF at `path` (its meshes must lie inside its own folder) and poses it at
/// `positions`.
pub fn assemble(path: &Path, positions: &BTreeMap<String, f64>) -> Result<Assembled, String> {
    assemble_posed(path, positions, positions)
}

/// [`assemble`] with the object's frame fixed by the visual bounding box at `frame_at` and the
/// links posed at `positions`: an articulated object drawn as its joints move keeps its frame
/// on its root link (the bounding box, and so `half`, are those at `frame_at`).
pub fn assemble_posed(
    path: &Path,
    frame_at: &BTreeMap<String, f64>,
    positions: &BTreeMap<String, f64>,
) -> Result<Assembled, String> {
    assemble_filled(path, &BTreeMap::new(), frame_at, positions)
}

/// A template's text with its placeholders filled, longest key first (so `DIM10` is not read
/// as `DIM1` followed by `0`).
pub fn fill_template(text: &str, fill: &BTreeMap<String, String>) -> Result<String, String> {
    let mut keys: Vec<(&String, &String)> = fill.iter().collect();
    for (k, v) in &keys {
        crate::spec::check_fill(k, v)?;
    }
    keys.sort_by_key(|(k, _)| std::cmp::Reverse(k.len()));
    let mut out = text.to_owned();
    for (k, v) in keys {
        out = out.replace(k.as_str(), v);
    }
    Ok(out)
}

/// [`assemble_posed`] of a template URDF filled with `fill` first (`Shape::Urdf::fill`).
pub fn assemble_filled(
    path: &Path,
    fill: &BTreeMap<String, String>,
    frame_at: &BTreeMap<String, f64>,
    positions: &BTreeMap<String, f64>,
) -> Result<Assembled, String> {
    let text =
        crate::assets::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let text = fill_template(&text, fill).map_err(|e| format!("{}: {e}", path.display()))?;
    let urdf = parse(&text).map_err(|e| format!("{}: {e}", path.display()))?;
    let dir = path.parent().unwrap_or(Path::new("."));
    let mut meshes: BTreeMap<String, TriangleMesh> = BTreeMap::new();
    let mut with_meshes = |parts: Vec<PlacedPart>| -> Result<Vec<_>, String> {
        parts
            .into_iter()
            .map(|p| {
                let mesh = match &p.geometry {
                    Geometry::Mesh { filename, .. } => {
                        if !meshes.contains_key(filename) {
                            let file = resolve_mesh(filename, dir, dir)?;
                            meshes.insert(filename.clone(), load_mesh(&file)?);
                        }
                        meshes.get(filename).cloned()
                    }
                    _ => None,
                };
                Ok((p, mesh))
            })
            .collect()
    };
    let framing = if frame_at == positions {
        None
    } else {
        Some(with_meshes(urdf.placed_visuals(frame_at)?)?)
    };
    let mut visuals = with_meshes(urdf.placed_visuals(positions)?)?;
    let mut collisions = with_meshes(urdf.placed_collisions(positions)?)?;
    let (mut lo, mut hi) = ([f64::MAX; 3], [f64::MIN; 3]);
    for (p, m) in framing.as_ref().unwrap_or(&visuals) {
        for c in part_corners(p, m.as_ref()) {
            for k in 0..3 {
                lo[k] = lo[k].min(c[k]);
                hi[k] = hi[k].max(c[k]);
            }
        }
    }
    if visuals.is_empty() || lo[0] > hi[0] {
        return Err(format!("{}: no visual geometry", path.display()));
    }
    let centre: [f64; 3] = std::array::from_fn(|k| (lo[k] + hi[k]) / 2.0);
    for (p, _) in visuals.iter_mut().chain(collisions.iter_mut()) {
        for (t, c) in p.pose.translation.iter_mut().zip(centre) {
            *t -= c;
        }
    }
    Ok(Assembled {
        visuals,
        collisions,
        half: std::array::from_fn(|k| (hi[k] - lo[k]) / 2.0),
        centre,
        urdf,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::FRAC_PI_2;

    #[test]
    fn templates_are_filled_with_numbers_and_file_names_only() {
        let fill = |pairs: &[(&str, &str)]| -> BTreeMap<String, String> {
            pairs
                .iter()
                .map(|(k, v)| (k.to_string(), v.to_string()))
                .collect()
        };
        let text = r#"<box size="DIM0 DIM1 DIM10"/><mesh filename="FNAME0"/>"#;
        let out = fill_template(
            text,
            &fill(&[
                ("DIM0", "0.04"),
                ("DIM1", "0.05"),
                ("DIM10", "0.06"),
                ("FNAME0", "03.obj"),
            ]),
        )
        .unwrap();
        assert_eq!(
            out,
            r#"<box size="0.04 0.05 0.06"/><mesh filename="03.obj"/>"#
        );
        for (k, v) in [
            ("DIM0", r#"0.04"/><include href="/etc/passwd"#),
            ("DIM0", "../secret.obj"),
            ("DIM0", "/abs.obj"),
            ("DIM0", "inf"),
            ("dim0", "0.04"),
            ("DIM", "0.04"),
            ("0", "0.04"),
        ] {
            assert!(fill_template(text, &fill(&[(k, v)])).is_err(), "{k} → {v}");
        }
    }

    const CABINET: &str = include_str!("../../../../examples/assets/cabinet/cabinet.urdf");

    fn cabinet_dir() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../examples/assets/cabinet")
    }

    fn at(pairs: &[(&str, f64)]) -> BTreeMap<String, f64> {
        pairs.iter().map(|(k, v)| (k.to_string(), *v)).collect()
    }

    #[track_caller]
    fn fails<T: std::fmt::Debug>(result: Result<T, String>, needle: &str) {
        let err = result.unwrap_err();
        assert!(
            err.contains(needle),
            "error {err:?} does not mention {needle:?}"
        );
    }

    fn close(a: &[f64], b: &[f64]) -> bool {
        a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-12)
    }

    /// A robot with links `a` and `b` and the given extra XML.
    fn robot(body: &str) -> String {
        format!(r#"<robot name="r"><link name="a"/><link name="b"/>{body}</robot>"#)
    }

    fn joint_xml(kind: &str, inner: &str) -> String {
        format!(
            r#"<joint name="j1" type="{kind}"><parent link="a"/><child link="b"/>{inner}</joint>"#
        )
    }

    #[test]
    fn cabinet_fixture_parses() {
        let u = parse(CABINET).unwrap();
        assert_eq!(u.name, "cabinet");
        let names: Vec<&str> = u.links.iter().map(|l| l.name.as_str()).collect();
        assert_eq!(names, ["body", "drawer", "door"]);
        assert_eq!(u.links[u.root()].name, "body");
        let body = &u.links[0];
        assert_eq!(body.visuals.len(), 6);
        assert!(
            body.visuals
                .iter()
                .all(|v| v.color == Some([0.62, 0.62, 0.64, 1.0]))
        );
        assert!(body.collisions.is_empty());
        let handle = &u.links[1].visuals[5];
        assert_eq!(
            handle.geometry,
            Geometry::Mesh {
                filename: "package://cabinet/meshes/handle.obj".into(),
                scale: [1.0; 3]
            }
        );
        assert_eq!(handle.color, Some([0.3, 0.3, 0.32, 1.0]));
        // "wood" is defined inline by the drawer front and referenced by name afterwards.
        assert_eq!(u.links[1].visuals[1].color, Some([0.55, 0.4, 0.25, 1.0]));
        assert_eq!(u.links[2].collisions.len(), 1);
        assert_eq!(u.links[2].collisions[0].color, None);
        let [slide, hinge] = &u.joints[..] else {
            panic!("two joints")
        };
        assert_eq!(
            (slide.kind, slide.parent, slide.child),
            (JointKind::Prismatic, 0, 1)
        );
        assert_eq!(
            (slide.axis, slide.limit),
            ([1.0, 0.0, 0.0], Some([0.0, 0.15]))
        );
        assert_eq!(
            (hinge.kind, hinge.axis, hinge.limit),
            (JointKind::Revolute, [0.0, 0.0, -1.0], Some([0.0, 1.57]))
        );
        // Collisions fall back to visuals for body and drawer; the door has its own box.
        assert_eq!(u.placed_collisions(&at(&[])).unwrap().len(), 6 + 6 + 1);
    }

    /// Axis-aligned bounds of the placed boxes of one link.
    fn boxes(u: &Urdf, q: &BTreeMap<String, f64>) -> Vec<(usize, [f64; 3], [f64; 3])> {
        let mut out = Vec::new();
        for p in u.placed_visuals(q).unwrap() {
            let Geometry::Box { size } = p.geometry else {
                continue;
            };
            let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
            for c in 0..8 {
                let corner = [0, 1, 2].map(|i| size[i] * (f64::from(c >> i & 1) - 0.5));
                let w = p.pose.transform_point(corner);
                for i in 0..3 {
                    lo[i] = lo[i].min(w[i]);
                    hi[i] = hi[i].max(w[i]);
                }
            }
            out.push((p.link, lo, hi));
        }
        out
    }

    #[test]
    fn cabinet_stands_on_the_ground_and_links_do_not_interpenetrate() {
        let u = parse(CABINET).unwrap();
        for q in [
            at(&[]),
            at(&[("drawer_slide", 0.15), ("door_hinge", 1.57)]),
            at(&[("drawer_slide", 0.07), ("door_hinge", 0.8)]),
        ] {
            let b = boxes(&u, &q);
            let min_z = b
                .iter()
                .map(|(_, lo, _)| lo[2])
                .fold(f64::INFINITY, f64::min);
            assert!(min_z.abs() < 1e-9, "lowest point {min_z}");
            for (i, (la, loa, hia)) in b.iter().enumerate() {
                for (lb, lob, hib) in &b[i + 1..] {
                    let overlap = (0..3).all(|k| loa[k].max(lob[k]) < hia[k].min(hib[k]) - 1e-9);
                    assert!(la == lb || !overlap, "{q:?}: links {la} and {lb} overlap");
                }
            }
        }
        let b = boxes(&u, &at(&[]));
        let (lo, hi) =
            b.iter()
                .filter(|p| p.0 == 0)
                .fold(([9.0_f64; 3], [-9.0_f64; 3]), |(lo, hi), p| {
                    (
                        [0, 1, 2].map(|k| lo[k].min(p.1[k])),
                        [0, 1, 2].map(|k| hi[k].max(p.2[k])),
                    )
                });
        assert!(
            close(&lo, &[-0.15, -0.12, 0.0]) && close(&hi, &[0.15, 0.12, 0.2]),
            "{lo:?} {hi:?}"
        );
    }

    #[test]
    fn prismatic_joint_moves_child_parts_along_its_axis() {
        let u = parse(CABINET).unwrap();
        let closed = u.placed_visuals(&at(&[])).unwrap();
        let open = u.placed_visuals(&at(&[("drawer_slide", 0.1)])).unwrap();
        for (c, o) in closed.iter().zip(&open) {
            let expected = if c.link == 1 { 0.1 } else { 0.0 };
            assert!(close(
                &o.pose.translation,
                &[
                    c.pose.translation[0] + expected,
                    c.pose.translation[1],
                    c.pose.translation[2]
                ]
            ));
            assert!(close(&o.pose.rotation, &c.pose.rotation));
        }
    }

    #[test]
    fn revolute_joint_rotates_about_its_axis() {
        let u = parse(&robot(&joint_xml(
            "revolute",
            r#"<origin xyz="1 0 0"/><axis xyz="0 0 2"/><limit lower="-3.2" upper="3.2"/>"#,
        )))
        .unwrap();
        let poses = u.link_poses(&at(&[("j1", FRAC_PI_2)])).unwrap();
        assert!(close(&poses[1].rotate([1.0, 0.0, 0.0]), &[0.0, 1.0, 0.0]));
        assert!(close(
            &poses[1].transform_point([1.0, 0.0, 0.0]),
            &[1.0, 1.0, 0.0]
        ));
        // The hinge swings the door out of the cabinet (+x) as it opens.
        let cabinet = parse(CABINET).unwrap();
        let door = cabinet.link_poses(&at(&[("door_hinge", 1.0)])).unwrap()[2];
        assert!(close(
            &door.rotate([0.0, 1.0, 0.0]),
            &[1f64.sin(), 1f64.cos(), 0.0]
        ));
    }

    #[test]
    fn rpy_is_fixed_axis_roll_pitch_yaw() {
        // Roll 90° then yaw 90° (about fixed axes): X → Y, Y → Z, Z → X.
        let p = Pose {
            translation: [0.0; 3],
            rotation: quat_from_rpy([FRAC_PI_2, 0.0, FRAC_PI_2]),
        };
        assert!(close(&p.rotate([1.0, 0.0, 0.0]), &[0.0, 1.0, 0.0]));
        assert!(close(&p.rotate([0.0, 1.0, 0.0]), &[0.0, 0.0, 1.0]));
        assert!(close(&p.rotate([0.0, 0.0, 1.0]), &[1.0, 0.0, 0.0]));
        // A general angle against the matrix product Rz · Ry · Rx.
        let (r, pi, y): (f64, f64, f64) = (0.3, -0.7, 1.1);
        let (cr, sr, cp, sp, cy, sy) = (r.cos(), r.sin(), pi.cos(), pi.sin(), y.cos(), y.sin());
        let m = [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ];
        let p = Pose::from_origin(&Origin {
            xyz: [1.0, 2.0, 3.0],
            rpy: [r, pi, y],
        });
        let v = [0.4, -1.3, 2.2];
        let mv = m.map(|row| row[0] * v[0] + row[1] * v[1] + row[2] * v[2]);
        assert!(close(&p.rotate(v), &mv));
        assert!(close(
            &p.transform_point(v),
            &[mv[0] + 1.0, mv[1] + 2.0, mv[2] + 3.0]
        ));
        // Composition: two quarter turns about Z, each 1 m along the local X.
        let step = Pose::from_origin(&Origin {
            xyz: [1.0, 0.0, 0.0],
            rpy: [0.0, 0.0, FRAC_PI_2],
        });
        let two = step.compose(&step);
        assert!(close(&two.translation, &[1.0, 1.0, 0.0]));
        assert!(close(&two.rotate([1.0, 0.0, 0.0]), &[-1.0, 0.0, 0.0]));
    }

    #[test]
    fn positions_are_checked_against_limits_and_names() {
        let u = parse(CABINET).unwrap();
        let err = "joint 'drawer_slide': position 0.2 is outside its limits [0, 0.15]";
        fails(u.link_poses(&at(&[("drawer_slide", 0.2)])), err);
        fails(u.link_poses(&at(&[("door_hinge", -0.1)])), "door_hinge");
        fails(u.link_poses(&at(&[("door_hinge", f64::NAN)])), "not finite");
        fails(
            u.link_poses(&at(&[("nope", 0.0)])),
            "'nope' is not a movable joint",
        );
        let fixed = parse(&robot(&joint_xml("fixed", ""))).unwrap();
        fails(fixed.link_poses(&at(&[("j1", 0.0)])), "'j1'");
        // Without a position a joint sits at 0, or at its lower limit when 0 is outside.
        let raised = parse(&robot(&joint_xml(
            "prismatic",
            r#"<axis xyz="0 0 1"/><limit lower="0.1" upper="0.2"/>"#,
        )))
        .unwrap();
        assert!(close(
            &raised.link_poses(&at(&[])).unwrap()[1].translation,
            &[0.0, 0.0, 0.1]
        ));
        // A limit element without bounds means [0, 0], as in URDF.
        let stuck = parse(&robot(&joint_xml(
            "revolute",
            r#"<limit effort="1" velocity="1"/>"#,
        )))
        .unwrap();
        assert_eq!(stuck.joints[0].limit, Some([0.0, 0.0]));
    }

    /// One case a line: a document, ` => `, and what its error must contain. `<ab>` stands for
    /// `<robot name="r"><link name="a"/><link name="b"/>`, and `<j TYPE>` for the start of a joint
    /// `j1` of that type from `a` to `b`.
    const MALFORMED: &str = r#"
        not xml < => XML
        <robot/> => robot: missing attribute 'name'
        <model/> => root element is <model>, not <robot>
        <robot name="r"/> => robot has no links
        <robot name="r"><link/></robot> => link 0: missing attribute 'name'
        <ab><link name="a"/></robot> => duplicate link 'a'
        <ab><link name="drawer"><visual><geometry><box size="0.1 x"/></geometry></visual></link></robot> => link 'drawer': visual 0: geometry: box size "0.1 x": expected 3 numbers
        <ab><link name="c"><visual><geometry><sphere radius="nan"/></geometry></visual></link></robot> => link 'c': visual 0: geometry: sphere radius "nan": numbers must be finite
        <ab><link name="c"><visual><geometry><cylinder radius="-1" length="1"/></geometry></visual></link></robot> => link 'c': visual 0: geometry: cylinder radius "-1": must not be negative
        <ab><link name="c"><visual><geometry><cylinder radius="1"/></geometry></visual></link></robot> => link 'c': visual 0: geometry: cylinder missing attribute 'length'
        <ab><link name="c"><visual><geometry><mesh/></geometry></visual></link></robot> => link 'c': visual 0: geometry: mesh missing attribute 'filename'
        <ab><link name="c"><visual><geometry><capsule/></geometry></visual></link></robot> => link 'c': visual 0: geometry: unknown shape <capsule>
        <ab><link name="c"><visual><origin xyz="inf 0 0"/></visual></link></robot> => link 'c': visual 0: origin: xyz "inf 0 0": numbers must be finite
        <ab><link name="c"><collision/></link></robot> => link 'c': collision 0: missing <geometry>
        <ab><link name="c"><visual><material name="gold"/><geometry><sphere radius="1"/></geometry></visual></link></robot> => link 'c': visual 0: material 'gold': no <color> here and not defined at robot level
        <ab><material name="m"><color rgba="1 0 0"/></material></robot> => material 'm': color rgba "1 0 0": expected 4 numbers
        <ab><material name="m"><color rgba="1 0 0 2"/></material></robot> => material 'm': color rgba [1.0, 0.0, 0.0, 2.0]: components must lie in [0, 1]
        <ab><j fixed></joint><j fixed></joint></robot> => duplicate joint 'j1'
        <ab><joint name="j1" type="fixed"><parent link="a"/><child link="foo"/></joint></robot> => joint 'j1': unknown child link 'foo'
        <ab><joint name="j1" type="fixed"><child link="b"/></joint></robot> => joint 'j1': missing <parent>
        <ab><joint name="j1"><parent link="a"/><child link="b"/></joint></robot> => joint 'j1': missing attribute 'type'
        <ab><j floating></joint></robot> => joint 'j1': type 'floating' is not supported
        <ab><j planar></joint></robot> => joint 'j1': type 'planar' is not supported
        <ab><j ball></joint></robot> => joint 'j1': unknown type 'ball'
        <ab><j continuous><axis xyz="0 0 0"/></joint></robot> => joint 'j1': axis xyz [0.0, 0.0, 0.0]: zero length
        <ab><j continuous><origin rpy="0 0"/></joint></robot> => joint 'j1': origin: rpy "0 0": expected 3 numbers
        <ab><j revolute></joint></robot> => joint 'j1': missing <limit> (required for revolute joints)
        <ab><j prismatic></joint></robot> => joint 'j1': missing <limit> (required for prismatic joints)
        <ab><j prismatic><limit lower="1" upper="0"/></joint></robot> => joint 'j1': limit: lower 1 is above upper 0
        <ab><j prismatic><limit lower="a"/></joint></robot> => joint 'j1': limit: lower "a": expected a number
        <ab></robot> => several root links (a, b): joints must connect all links into one tree
        <ab><link name="c"/><j fixed></joint><joint name="j2" type="fixed"><parent link="c"/><child link="b"/></joint></robot> => link 'b' has two parent joints ('j1' and 'j2')
        <ab><j fixed></joint><joint name="j2" type="fixed"><parent link="b"/><child link="a"/></joint></robot> => no root link: the joints form a cycle
        <ab><link name="c"/><link name="d"/><j fixed></joint><joint name="j2" type="fixed"><parent link="c"/><child link="d"/></joint><joint name="j3" type="fixed"><parent link="d"/><child link="c"/></joint></robot> => joint 'j2': part of a cycle of joints not connected to the root link 'a'
    "#;

    #[test]
    fn malformed_documents_are_rejected_with_the_place_and_reason() {
        for line in MALFORMED.lines().map(str::trim).filter(|l| !l.is_empty()) {
            let (text, expected) = line.split_once(" => ").unwrap();
            let mut text = text.replace(
                "<ab>",
                r#"<robot name="r"><link name="a"/><link name="b"/>"#,
            );
            while let Some(i) = text.find("<j ") {
                let end = i + text[i..].find('>').unwrap();
                let kind = text[i + 3..end].to_owned();
                let joint = format!(
                    r#"<joint name="j1" type="{kind}"><parent link="a"/><child link="b"/>"#
                );
                text.replace_range(i..=end, &joint);
            }
            let err = parse(&text).unwrap_err();
            assert!(
                err.contains(expected),
                "{text}\n gave: {err}\n expected: {expected}"
            );
        }
    }

    #[test]
    fn mesh_paths_resolve_inside_the_asset_root_only() {
        let dir = cabinet_dir();
        let handle = dir.join("meshes/handle.obj").canonicalize().unwrap();
        let assets = dir.join("..");
        for name in [
            "package://cabinet/meshes/handle.obj",
            "meshes/handle.obj",
            "file://meshes/handle.obj",
        ] {
            assert_eq!(resolve_mesh(name, &dir, &assets).unwrap(), handle, "{name}");
        }
        // Found through asset_root/<package>/... when not beside the URDF.
        assert_eq!(
            resolve_mesh(
                "package://cabinet/meshes/handle.obj",
                Path::new("/nonexistent"),
                &assets
            )
            .unwrap(),
            handle
        );
        let meshes = dir.join("meshes");
        fails(
            resolve_mesh("../cabinet.urdf", &meshes, &meshes),
            "escapes the asset root",
        );
        let deep = "../".repeat(40) + "etc/passwd";
        if Path::new("/etc/passwd").exists() {
            fails(resolve_mesh(&deep, &dir, &assets), "escapes the asset root");
            fails(
                resolve_mesh("file:///etc/passwd", &dir, &assets),
                "escapes the asset root",
            );
        }
        fails(
            resolve_mesh("meshes/missing.obj", &dir, &assets),
            "not found",
        );
        fails(
            resolve_mesh("http://x/y.obj", &dir, &assets),
            "unsupported URL scheme",
        );
    }

    fn cube() -> Vec<[[f32; 3]; 3]> {
        let v = |i: usize| [0, 1, 2].map(|k| (i >> k & 1) as f32);
        let quads = [
            [0, 4, 6, 2],
            [1, 3, 7, 5],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 2, 3, 1],
            [4, 5, 7, 6],
        ];
        quads
            .iter()
            .flat_map(|[a, b, c, d]| [[v(*a), v(*b), v(*c)], [v(*a), v(*c), v(*d)]])
            .collect()
    }

    /// Asserts that the mesh is closed and consistently oriented (every edge, welded by position,
    /// is used once in each direction) and returns its signed volume.
    fn closed_volume(m: &TriangleMesh) -> f64 {
        let key = |i: u32| m.vertices[i as usize].map(f32::to_bits);
        let mut edges = BTreeMap::new();
        let mut volume = 0.0;
        for t in &m.triangles {
            for k in 0..3 {
                *edges.entry((key(t[k]), key(t[(k + 1) % 3]))).or_insert(0) += 1;
            }
            let [a, b, c] = t.map(|i| m.vertices[i as usize].map(f64::from));
            volume += (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                + a[2] * (b[0] * c[1] - b[1] * c[0]))
                / 6.0;
        }
        for ((a, b), n) in &edges {
            assert_eq!(
                (*n, edges.get(&(*b, *a))),
                (1, Some(&1)),
                "edge {a:?} -> {b:?}"
            );
        }
        volume
    }

    #[test]
    fn stl_ascii_and_binary_cubes() {
        let mut ascii = String::from("solid cube\n");
        let mut binary = b"solid but actually binary".to_vec();
        binary.resize(80, 0);
        binary.extend(12u32.to_le_bytes());
        for t in cube() {
            ascii += "facet normal 0 0 0\n outer loop\n";
            binary.extend([0u8; 12]);
            for p in t {
                ascii += &format!("  vertex {} {} {}\n", p[0], p[1], p[2]);
                binary.extend(p.iter().flat_map(|c| c.to_le_bytes()));
            }
            ascii += " endloop\nendfacet\n";
            binary.extend([0u8; 2]);
        }
        ascii += "endsolid cube\n";
        for m in [
            parse_stl(ascii.as_bytes()).unwrap(),
            parse_stl(&binary).unwrap(),
        ] {
            assert_eq!((m.triangles.len(), m.vertices.len()), (12, 36));
            assert!((closed_volume(&m) - 1.0).abs() < 1e-9);
        }
        fails(parse_stl(&binary[..binary.len() - 1]), "neither binary");
        fails(
            parse_stl(b"solid x\nfacet\nouter loop\nvertex 0 0 0\nendloop\nendfacet\n"),
            "invalid facet header",
        );
        fails(parse_stl(b"solid x\nendsolid x\n"), "no triangles");
        // An unnamed solid, CRLF line ends and leading blanks are ASCII STL too.
        let unnamed = ascii
            .replacen("solid cube", "  solid", 1)
            .replace('\n', "\r\n");
        assert_eq!(parse_stl(unnamed.as_bytes()).unwrap().triangles.len(), 12);
        fails(parse_stl(b"solidly not stl"), "neither binary");
    }

    #[test]
    fn fixture_meshes_load_as_closed_shapes() {
        let u = parse(CABINET).unwrap();
        let dir = cabinet_dir();
        let mut loaded = 0;
        for part in u.links.iter().flat_map(|l| &l.visuals) {
            if let Geometry::Mesh { filename, .. } = &part.geometry {
                let mesh =
                    load_mesh(&resolve_mesh(filename, &dir, &dir.join("..")).unwrap()).unwrap();
                assert!(closed_volume(&mesh) > 0.0, "{filename}");
                loaded += 1;
            }
        }
        assert_eq!(loaded, 2);
        let err = "unsupported mesh format 'dae' (convert to OBJ or STL)";
        fails(load_mesh(Path::new("meshes/handle.dae")), err);
    }
}
