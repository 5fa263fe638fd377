"""Runs one GenSim task's reset() against a recording stand-in of the Ravens API and prints what it
built, as JSON on standard output, for `assay import gensim` (crates/import/src/gensim/).

    python -I recorder.py ASSETS LIBRARY TASK_FILE SEED [SEED ...]   (run by the importer, sandboxed)
    python -I recorder.py --probe     (assay doctor: sets the limits and the boundary, says what held)

Nothing of the task is trusted. The importer starts this script with an empty environment and
kills it after a wall-clock timeout; here, before the task's code is read:
  - hard limits on CPU time and address space (from the importer), file size 0, no processes and
    no core file (`limit()`: hard, so that nothing can raise them again);
  - the task module gets its own builtins: no open, exec, eval, compile, input or breakpoint, and
    an __import__ that gives numpy, the standard modules a task computes with, the Ravens stand-ins
    (cliport, pybullet) and a stand-in `os` that has only `os.path`; any other import gives an
    inert stub (no module is loaded), and using it refuses the task (`Unused`);
  - an audit hook (it cannot be removed) stops the process on any file write, any read outside the
    library and Python's own files, any process, socket, signal or ctypes call, and any import of a
    module that could reach them, whatever path the code found to it;
  - what the task prints is dropped, so that only this script writes the answer;
  - and under all of that, the OS boundary, where the kernel allows it (`confine()`): a Landlock
    domain that reads the library, the assets, Python and the system libraries only, writes
    nowhere and makes no TCP connection, and a seccomp filter that answers EPERM to processes,
    program execution, sockets, tracing, mounts and namespaces; the importer also starts this
    script in a network namespace of its own. These hold whatever path the code finds around the
    guards (ctypes, numpy's C paths): the importer's tests run hostile code with the guards off.

The stand-in follows GenSim's own `cliport/tasks/task.py`, `environments/environment.py` and
`utils/utils.py` (the library's `reference/`): templates are filled as `fill_template` and
`fill_dummy_template` fill them (the values are recorded, not written to a file), random poses are
drawn as `get_random_pose` draws them (a free pixel of a top-down grid of what the assets cover,
eroded by the declared size, with the same numpy calls), goals are recorded with their matches, targets,
symmetries and metric. The answer is one JSON object: {"seeds": [...]} or {"refused": {field,
reason}}; the importer translates it into a task spec."""

import sys, os as _os

_REAL_STDOUT = _os.dup(1)


def _answer(obj, code=0):
    import json as _json
    data = (_json.dumps(obj) + "\n").encode()
    view = memoryview(data)
    while view:
        n = _os.write(_REAL_STDOUT, view)
        view = view[n:]
    _os._exit(code)


class _Bounded:
    """What the task prints: counted and dropped, never on the answer's stream."""

    def __init__(self):
        self.n = 0

    def write(self, s):
        self.n += len(s)
        return len(s)

    def flush(self):
        pass


sys.stdout = _Bounded()
sys.stderr = _Bounded()

import json, math, random, types, copy, itertools, functools, collections, string, re
import xml.etree.ElementTree as _ET
try:
    import numpy as np
except ImportError:
    _answer({'error': f"numpy is not installed for {sys.executable or _os.environ.get('ASSAY_RECORDER_PYTHON', 'python')} (GenSim task code needs it: "
                      "pip install numpy, or point ASSAY_PYTHON at a Python that has it)"}, 2)

# `--probe`: set the limits and the OS boundary, and say what held (assay doctor).
PROBE = sys.argv[1:2] == ['--probe']
if not PROBE:
    ASSETS = _os.path.realpath(sys.argv[1])
    LIBRARY = _os.path.realpath(sys.argv[2])
    TASK_FILE = _os.path.realpath(sys.argv[3])
    SEEDS = [int(s) for s in sys.argv[4:]]
# Only the importer's own tests set these (the importer clears the environment and sets neither):
# one runs task code without the Python guards, to show the OS boundary holds alone; the other
# without the OS boundary too, to show that the test can tell.
UNGUARDED = _os.environ.get('ASSAY_RECORDER_TEST_UNGUARDED') == '1'
NO_BOUNDARY = _os.environ.get('ASSAY_RECORDER_TEST_NO_BOUNDARY') == '1'
# What task code sees as self.assets_root: paths built from it are recorded relative to the assets.
ASSETS_TOKEN = "assets"


class Refused(Exception):
    """The task does something a recording cannot follow, or must not do."""

    def __init__(self, field, reason):
        super().__init__(reason)
        self.field, self.reason = field, reason


# ---------------------------------------------------------------------------------------------
# Geometry (utils.py).

def quat_from_euler(r):
    cx, sx = math.cos(r[0] / 2), math.sin(r[0] / 2)
    cy, sy = math.cos(r[1] / 2), math.sin(r[1] / 2)
    cz, sz = math.cos(r[2] / 2), math.sin(r[2] / 2)
    return (sx * cy * cz - cx * sy * sz, cx * sy * cz + sx * cy * sz,
            cx * cy * sz - sx * sy * cz, cx * cy * cz + sx * sy * sz)


def euler_from_quat(q):
    x, y, z, w = [float(v) for v in q]
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return (roll, pitch, yaw)


def rot_matrix(q):
    x, y, z, w = [float(v) for v in q]
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def quat_mul(a, b):
    x1, y1, z1, w1 = a
    x2, y2, z2, w2 = b
    return (w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2, w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2, w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2)


def as_pose(pose, field):
    """A pose as GenSim accepts it: (position, quaternion), or a bare position."""
    try:
        if len(pose) == 3 and not hasattr(pose[0], "__len__"):
            pose = (pose, (0, 0, 0, 1))
        pos = [float(v) for v in pose[0]]
        rot = [float(v) for v in pose[1]]
    except Exception:
        raise Refused(field, f"not a pose: {pose!r}"[:200])
    if len(pos) != 3 or len(rot) != 4 or not all(math.isfinite(v) for v in pos + rot):
        raise Refused(field, f"not a finite (position, quaternion) pose: {pose!r}"[:200])
    return pos, rot


COLORS_DICT = {
    'blue': [78.0 / 255.0, 121.0 / 255.0, 167.0 / 255.0],
    'red': [255.0 / 255.0, 87.0 / 255.0, 89.0 / 255.0],
    'green': [89.0 / 255.0, 169.0 / 255.0, 78.0 / 255.0],
    'orange': [242.0 / 255.0, 142.0 / 255.0, 43.0 / 255.0],
    'yellow': [237.0 / 255.0, 201.0 / 255.0, 72.0 / 255.0],
    'purple': [176.0 / 255.0, 122.0 / 255.0, 161.0 / 255.0],
    'pink': [255.0 / 255.0, 157.0 / 255.0, 167.0 / 255.0],
    'cyan': [118.0 / 255.0, 183.0 / 255.0, 178.0 / 255.0],
    'brown': [156.0 / 255.0, 117.0 / 255.0, 95.0 / 255.0],
    'white': [255.0 / 255.0, 255.0 / 255.0, 255.0 / 255.0],
    'gray': [186.0 / 255.0, 176.0 / 255.0, 172.0 / 255.0],
    'indigo': [75.0 / 255.0, 0.0 / 255.0, 130.0 / 255.0],
    'violet': [143.0 / 255.0, 0.0 / 255.0, 255.0 / 255.0],
    'black': [0.0, 0.0, 0.0],
    'silver': [192.0 / 255.0, 192.0 / 255.0, 192.0 / 255.0],
    'gold': [255.0 / 255.0, 215.0 / 255.0, 0.0 / 255.0],
}


def color_record(color):
    """(rgb, name): a colour name where the rgb is one of utils.COLORS."""
    if color is None:
        return None, None
    if isinstance(color, str):
        color = COLORS_DICT.get(color, [1.0, 0.0, 0.0])
    try:
        rgb = [float(c) for c in list(color)[:3]]
    except Exception:
        raise Refused("color", f"not a colour: {color!r}"[:200])
    if len(rgb) != 3 or not all(math.isfinite(c) for c in rgb):
        raise Refused("color", f"not a colour: {color!r}"[:200])
    for name, value in COLORS_DICT.items():
        if all(abs(a - b) < 1e-6 for a, b in zip(rgb, value)):
            return rgb, name
    return rgb, None


# ---------------------------------------------------------------------------------------------
# The recording environment.

class Env:
    def __init__(self):
        self.objects = []
        self.obj_ids = {'fixed': [], 'rigid': [], 'deformable': []}
        # What the objects cover seen from above, as GenSim's sampler reads it from the scene it
        # rendered: (position, yaw, shapes in the object's frame) per object added.
        self.footprints = []
        self.task = None

    def add_object(self, urdf, pose, category='rigid', color=None, **kwargs):
        field = f"env.add_object[{len(self.objects)}]"
        pos, rot = as_pose(pose, field)
        if not isinstance(urdf, str):
            raise Refused(field, f"the URDF argument is not a path: {urdf!r}"[:200])
        if category not in ('fixed', 'rigid', 'deformable'):
            raise Refused(field, f"unknown category {category!r}")
        record = TEMPLATES.get(urdf)
        if record is not None:
            path, fill = record['template'], dict(record['fill'])
            if color is None and record.get('color') is not None:
                color = record['color']
        else:
            path, fill = assets_relative(urdf, field), {}
        if 'template' in path:
            if not _os.path.exists(_os.path.join(ASSETS, path)):
                path = path.replace('-template', '')
            fill_dummy(path, fill)
        if not _os.path.exists(_os.path.join(ASSETS, path)):
            raise Refused(field, f"URDF '{path}' does not exist under the assets (GenSim would "
                                 "silently load a substitute block; the importer does not)")
        rgb, name = color_record(color)
        if path.endswith('.urdf') and 'COLOR0' in template_text(path) and 'COLOR0' not in fill:
            # GenSim writes the colour into the template's rgba (white where none is given).
            for i in range(3):
                fill[f'COLOR{i}'] = rgb[i] if rgb is not None else 1.0
        oid = len(self.objects) + 1
        self.objects.append({'id': oid, 'urdf': path, 'fill': fill, 'pose': [pos, rot],
                             'category': category, 'color': rgb, 'color_name': name,
                             'pile': False})
        self.obj_ids.setdefault(category, []).append(oid)
        # What later draws keep clear of: the asset as drawn, at the pose it was given.
        yaw = euler_from_quat(rot)[2]
        shapes = asset_shapes(path, fill) or [('disc', 0.0, 0.0, 0.03)]
        self.footprints.append((pos[0], pos[1], yaw, shapes))
        return oid

    def __getattr__(self, name):
        raise Refused(f"env.{name}", "not part of the Ravens environment a task may use "
                                     "(the importer records add_object and obj_ids)")


def assets_relative(path, field):
    """A path task code built from self.assets_root (or a bare asset path), relative to the
    assets; refused when it leaves them."""
    p = path
    if p.startswith(ASSETS_TOKEN + "/"):
        p = p[len(ASSETS_TOKEN) + 1:]
    full = _os.path.realpath(_os.path.join(ASSETS, p))
    if not (full == ASSETS or full.startswith(ASSETS + _os.sep)):
        raise Refused(field, f"'{path}' leaves the library's assets")
    return _os.path.relpath(full, ASSETS)


TEMPLATES = {}
# What an asset covers in x, y, in its own frame, as filled ((path, fill) → shapes, or None).
SHAPES = {}


def asset_shapes(path, fill):
    """What a URDF collides with seen from above, in its own frame, as the task filled it: boxes
    ('box', cx, cy, hx, hy: an OBJ mesh as the box about its vertices) and discs ('disc', cx, cy,
    r: cylinders, spheres), each link placed by its joints' offsets (their turns are not
    followed), its visuals where a link has no collision; None where the file cannot tell."""
    key = (path, tuple(sorted((k, str(v)) for k, v in fill.items())))
    if key not in SHAPES:
        try:
            SHAPES[key] = _shapes(path, fill)
        except Exception:
            SHAPES[key] = None
    return SHAPES[key]


def _xyz(element, attr='xyz'):
    origin = element.find('origin') if element is not None else None
    text = origin.get(attr, '0 0 0') if origin is not None else '0 0 0'
    return [float(v) for v in text.split()]


def _shapes(path, fill):
    if not path.endswith('.urdf'):
        return None
    text = template_text(path)
    for k, v in sorted(fill.items(), key=lambda kv: -len(kv[0])):
        text = text.replace(k, str(v))
    root = _ET.fromstring(text)
    links = {l.get('name'): l for l in root.findall('link')}
    offset = {name: None for name in links}
    children = {j.find('child').get('link') for j in root.findall('joint')}
    for name in links:
        if name not in children:
            offset[name] = (0.0, 0.0)
    for _ in range(len(links)):
        for j in root.findall('joint'):
            parent, child = j.find('parent').get('link'), j.find('child').get('link')
            if offset.get(parent) is not None and offset.get(child) is None:
                x, y = _xyz(j)[:2]
                offset[child] = (offset[parent][0] + x, offset[parent][1] + y)
    shapes = []
    for name, link in links.items():
        ox, oy = offset[name] or (0.0, 0.0)
        for shape in link.findall('collision') or link.findall('visual'):
            x, y = _xyz(shape)[:2]
            x, y = x + ox, y + oy
            g = shape.find('geometry')
            if g is None or len(g) == 0:
                continue
            g = g[0]
            if g.tag == 'box':
                sx, sy = [float(v) for v in g.get('size').split()][:2]
                shapes.append(('box', x, y, sx / 2, sy / 2))
            elif g.tag in ('cylinder', 'sphere'):
                shapes.append(('disc', x, y, float(g.get('radius'))))
            elif g.tag == 'mesh':
                box = _mesh_box(path, g.get('filename'), g.get('scale', '1 1 1'))
                if box is None:
                    return None
                (x0, x1), (y0, y1) = box
                shapes.append(('box', x + (x0 + x1) / 2, y + (y0 + y1) / 2, (x1 - x0) / 2,
                               (y1 - y0) / 2))
            else:
                return None
    return shapes or None


def _mesh_box(urdf, filename, scale):
    """The box about an OBJ mesh's vertices in x, y, scaled."""
    if not filename or not filename.lower().endswith('.obj'):
        return None
    full = _os.path.realpath(_os.path.join(ASSETS, _os.path.dirname(urdf), filename))
    if not full.startswith(ASSETS + _os.sep):
        return None
    sx, sy = [float(v) for v in scale.split()][:2]
    xs, ys = [], []
    with open(full) as f:
        for line in f:
            if line.startswith('v '):
                x, y = line.split()[1:3]
                xs.append(float(x) * sx)
                ys.append(float(y) * sy)
    if not xs:
        return None
    return (min(xs), max(xs)), (min(ys), max(ys))


def occupied(footprints, bounds, pix):
    """The pixels of GenSim's top-down grid over `bounds` that the footprints cover (a pixel
    (u, v) is y = bounds[1, 0] + u·pix, x = bounds[0, 0] + v·pix, as `utils.pix_to_xyz`)."""
    h = int(np.round((bounds[1, 1] - bounds[1, 0]) / pix))
    w = int(np.round((bounds[0, 1] - bounds[0, 0]) / pix))
    mask = np.zeros((h, w), dtype=bool)
    for x, y, yaw, shapes in footprints:
        c, s = math.cos(yaw), math.sin(yaw)
        for shape in shapes:
            kind, cx, cy = shape[:3]
            wx, wy = x + c * cx - s * cy, y + s * cx + c * cy
            reach = shape[3] if kind == 'disc' else math.hypot(shape[3], shape[4])
            v0 = max(int((wx - reach - bounds[0, 0]) / pix) - 1, 0)
            v1 = min(int((wx + reach - bounds[0, 0]) / pix) + 2, w)
            u0 = max(int((wy - reach - bounds[1, 0]) / pix) - 1, 0)
            u1 = min(int((wy + reach - bounds[1, 0]) / pix) + 2, h)
            if v0 >= v1 or u0 >= u1:
                continue
            px = bounds[0, 0] + (np.arange(v0, v1) + 0.5) * pix - wx
            py = bounds[1, 0] + (np.arange(u0, u1) + 0.5) * pix - wy
            dx, dy = np.meshgrid(px, py)
            if kind == 'disc':
                inside = dx * dx + dy * dy <= reach * reach
            else:
                lx, ly = c * dx + s * dy, -s * dx + c * dy
                inside = (np.abs(lx) <= shape[3]) & (np.abs(ly) <= shape[4])
            mask[u0:u1, v0:v1] |= inside
    return mask


def erode(free, k):
    """cv2.erode(free, np.ones((k, k))): a pixel stays free where the k × k window about it
    (anchored at k // 2, outside the image counting as free) is all free."""
    if k <= 1:
        return free
    taken = (free == 0).astype(np.int64)
    h, w = taken.shape
    total = np.zeros((h + 1, w + 1), dtype=np.int64)
    total[1:, 1:] = taken.cumsum(0).cumsum(1)
    a = k // 2
    r0 = np.clip(np.arange(h) - a, 0, h)
    r1 = np.clip(np.arange(h) - a + k, 0, h)
    c0 = np.clip(np.arange(w) - a, 0, w)
    c1 = np.clip(np.arange(w) - a + k, 0, w)
    window = (total[r1][:, c1] - total[r0][:, c1] - total[r1][:, c0] + total[r0][:, c0])
    return (window == 0).astype(np.uint8)


def sample_distribution(prob, n_samples=1):
    """utils.sample_distribution, as GenSim's: the same draw from numpy's stream."""
    flat_prob = prob.flatten() / np.sum(prob)
    rand_ind = np.random.choice(np.arange(len(flat_prob)), n_samples, p=flat_prob, replace=False)
    rand_ind_coords = np.array(np.unravel_index(rand_ind, prob.shape)).T
    return np.int32(rand_ind_coords.squeeze())


def template_text(path):
    with open(_os.path.join(ASSETS, path)) as f:
        return f.read()


def fill_dummy(path, fill):
    """environment.py's fill_dummy_template: placeholders no one filled get random values."""
    text = template_text(path) if _os.path.exists(_os.path.join(ASSETS, path)) else ''
    for k, v in fill.items():
        text = text.replace(k, str(v))
    for fields, lo, hi in ((['DIMH', 'DIMR', 'DIMX', 'DIMY', 'DIMZ', 'DIM'], 0.03, 0.05),
                           (['HALF'], 0.01, 0.03)):
        for field in fields:
            if field in text:
                vals = np.random.uniform(lo, hi, size=(3,)).tolist()
                for i, v in enumerate(vals):
                    key = f'{field}{i}'
                    if key in text:
                        fill[key] = float(v)
                        text = text.replace(key, str(v))


def fill_template(self, template, replace):
    field = f"fill_template({template!r})"[:120]
    if not isinstance(replace, dict):
        raise Refused(field, "the replacement is not a dict")
    base = TEMPLATES.get(template)
    if base is not None:
        path, fill, color = base['template'], dict(base['fill']), base.get('color')
    else:
        path, fill, color = assets_relative(template, field), {}, None
        if not _os.path.exists(_os.path.join(ASSETS, path)):
            return template
    text = template_text(path)
    for key, values in replace.items():
        if not isinstance(key, str) or not re.fullmatch(r'[A-Z][A-Z_]*', key):
            raise Refused(field, f"replacement key {key!r} is not a template placeholder")
        if key == 'COLOR':
            color = values
            continue
        if isinstance(values, str):
            values = (values,)
        for i, v in enumerate(list(values)):
            name = f'{key}{i}'
            # Only what the template has: GenSim's replace of a missing key does nothing.
            if name in fill or name not in text:
                continue
            if isinstance(v, str):
                rel = assets_relative(v, f"{field}.{name}")
                rel = _os.path.relpath(rel, _os.path.dirname(path) or '.')
                if rel.startswith('..'):
                    raise Refused(f"{field}.{name}", f"'{v}' is not in the template's folder")
                fill[name] = rel
            else:
                try:
                    fill[name] = float(v)
                except Exception:
                    raise Refused(field, f"{name}: not a number or a file name: {v!r}"[:200])
    token = f'assay-template:{len(TEMPLATES)}'
    TEMPLATES[token] = {'template': path, 'fill': fill, 'color': color}
    return token


# ---------------------------------------------------------------------------------------------
# Stand-in modules.

def make_pybullet():
    p = types.ModuleType('pybullet')

    def get_pose(oid):
        o = ENV.objects[int(oid) - 1]
        return tuple(o['pose'][0]), tuple(o['pose'][1])

    def change_visual(oid, link=-1, rgbaColor=None, **kw):
        if rgbaColor is not None:
            rgb, name = color_record(rgbaColor)
            ENV.objects[int(oid) - 1]['color'] = rgb
            ENV.objects[int(oid) - 1]['color_name'] = name

    p.getBasePositionAndOrientation = get_pose
    p.changeVisualShape = change_visual
    p.stepSimulation = lambda *a, **k: None
    p.getQuaternionFromEuler = quat_from_euler
    p.getEulerFromQuaternion = euler_from_quat
    p.getMatrixFromQuaternion = lambda q: tuple(rot_matrix(q).flatten())

    def missing(name):
        raise Refused(f"pybullet.{name}", "a simulator call the recording cannot answer")
    p.__getattr__ = missing
    return p


def make_utils():
    u = types.ModuleType('cliport.utils.utils')
    u.COLORS = collections.defaultdict(lambda: [255.0 / 255.0, 0.0, 0.], COLORS_DICT)
    u.COLORS_NAMES = list(COLORS_DICT)
    u.TRAIN_COLORS = ['blue', 'red', 'green', 'yellow', 'brown', 'gray', 'cyan']
    u.EVAL_COLORS = ['blue', 'red', 'green', 'orange', 'purple', 'pink', 'white']

    def get_colors(mode, n_colors=-1, **kw):
        names = u.TRAIN_COLORS
        if n_colors != -1:
            names = random.sample(names, n_colors)
        return [u.COLORS[c] for c in names], names
    u.get_colors = get_colors
    u.get_colors_names = lambda mode: u.TRAIN_COLORS
    u.get_random_color = lambda: get_colors('train', 1)
    u.eulerXYZ_to_quatXYZW = quat_from_euler
    u.quatXYZW_to_eulerXYZ = euler_from_quat

    def apply(pose, position):
        position = np.float32(position)
        shape = position.shape
        position = position.reshape(3, -1)
        out = rot_matrix(pose[1]).astype(np.float32) @ position
        out = out + np.float32(pose[0]).reshape(3, 1)
        return tuple(out.reshape(shape))
    u.apply = apply

    def multiply(a, b):
        t = tuple(rot_matrix(a[1]) @ np.array(b[0], dtype=float) + np.array(a[0], dtype=float))
        return t, quat_mul([float(v) for v in a[1]], [float(v) for v in b[1]])
    u.multiply = multiply

    def invert(pose):
        x, y, z, w = [float(v) for v in pose[1]]
        qi = (-x, -y, -z, w)
        t = -(rot_matrix(qi) @ np.array(pose[0], dtype=float))
        return tuple(t), qi
    u.invert = invert
    u.map_kit_scale = lambda s: (s[0] / 10, s[1] / 10, s[2] / 10)
    u.assembling_kit_shapes = {i: n for i, n in enumerate([
        "letter R shape", "letter A shape", "triangle", "square", "plus", "letter T shape",
        "diamond", "pentagon", "rectangle", "flower", "star", "circle", "letter G shape",
        "letter V shape", "letter E shape", "letter L shape", "ring", "hexagon", "heart",
        "letter M shape"])}

    def missing(name):
        raise Refused(f"utils.{name}", "a helper the recording does not provide")
    u.__getattr__ = missing
    return u


def make_os():
    """`os` as task code may see it: paths only."""
    o = types.ModuleType('os')
    o.path = types.ModuleType('os.path')
    for name in ('join', 'basename', 'dirname', 'splitext', 'split', 'normpath'):
        setattr(o.path, name, getattr(_os.path, name))
    o.path.exists = lambda p: _os.path.exists(_os.path.join(ASSETS, assets_relative(p, 'os.path.exists')))
    o.sep = _os.sep

    def missing(name):
        raise Refused(f"os.{name}", "task code may use os.path only")
    o.__getattr__ = missing
    return o


class Task:
    def __init__(self):
        self.ee = 'suction'
        self.mode = 'train'
        self.sixdof = False
        self.primitive = 'pick-place'
        self.pos_eps = 0.01
        self.rot_eps = np.deg2rad(15)
        self.num_blocks = 50
        self.pix_size = 0.003125
        self.bounds = np.array([[0.25, 0.75], [-0.5, 0.5], [0, 0.3]])
        self.zone_bounds = np.copy(self.bounds)
        self.goals = []
        self.lang_goals = []
        self.task_completed_desc = 'task completed.'
        self.progress = 0
        self._rewards = 0
        self.train_set = np.arange(0, 14)
        self.test_set = np.arange(14, 20)
        self.assets_root = ASSETS_TOKEN
        self.homogeneous = False
        self.lang_template = ''
        self.obj_points_cache = {}

    def reset(self, env):
        self.goals = []
        self.lang_goals = []
        self.progress = 0
        self._rewards = 0

    def additional_reset(self):
        if 'bowl' in self.lang_template:
            self.pos_eps = 0.05
        if 'piles' in self.lang_template:
            self.ee = 'spatula'
            self.primitive = 'push'
        if 'rope' in self.lang_template:
            self.pos_eps = 0.02

    def get_random_pose(self, env, obj_size=0.1, **kw):
        """task.py's get_random_pose: a free pixel of the top-down grid, drawn as GenSim draws
        it (what the scene covers, the image's border, eroded by the object's diagonal; the
        centre where nothing is free), then a yaw."""
        if np.isscalar(obj_size):
            obj_size = (obj_size, obj_size, obj_size)
        obj_size = [float(s) for s in obj_size]
        max_size = np.sqrt(obj_size[0] ** 2 + obj_size[1] ** 2)
        erode_size = int(np.round(max_size / self.pix_size))
        taken = occupied(env.footprints, self.bounds, self.pix_size)
        free = np.ones(taken.shape, dtype=np.uint8)
        free[taken] = 0
        free[0, :], free[:, 0], free[-1, :], free[:, -1] = 0, 0, 0, 0
        free = erode(free, erode_size)
        if np.sum(free) == 0:
            pix = (free.shape[0] // 2, free.shape[1] // 2)
        else:
            pix = sample_distribution(np.float32(free))
        u, v = int(pix[0]), int(pix[1])
        x = float(self.bounds[0, 0] + v * self.pix_size)
        y = float(self.bounds[1, 0] + u * self.pix_size)
        z = 0.05 if len(obj_size) == 2 else obj_size[2] / 2
        theta = np.random.rand() * 2 * np.pi
        return [x, y, z], quat_from_euler((0, 0, theta))

    fill_template = fill_template

    def get_random_size(self, min_x, max_x, min_y, max_y, min_z, max_z):
        size = np.random.rand(3)
        size[0] = size[0] * (max_x - min_x) + min_x
        size[1] = size[1] * (max_y - min_y) + min_y
        size[2] = size[2] * (max_z - min_z) + min_z
        return tuple(size)

    def add_goal(self, objs, matches, targ_poses, replace, rotations, metric, params,
                 step_max_reward, symmetries=None, language_goal=None, **kw):
        field = f"add_goal[{len(self.goals)}]"
        ids, syms = [], []
        for k, o in enumerate(list(objs)):
            if isinstance(o, (tuple, list)):
                oid, sym = o[0], (o[1][0] if isinstance(o[1], (tuple, list)) else 0.0)
            else:
                oid, sym = o, None
            try:
                oid = int(oid)
            except Exception:
                raise Refused(f"{field}.objs[{k}]", f"not an object id: {o!r}"[:200])
            if not 1 <= oid <= len(ENV.objects):
                raise Refused(f"{field}.objs[{k}]", f"not an object id: {o!r}"[:200])
            ids.append(oid)
            syms.append(sym)
        if symmetries is not None:
            syms = [float(s) for s in list(symmetries)] + [0.0] * max(0, len(ids) - len(symmetries))
        syms = [0.0 if s is None else float(s) for s in syms][:len(ids)]
        targets = [as_pose(t, f"{field}.targ_poses[{k}]") for k, t in enumerate(list(targ_poses))]
        try:
            m = np.asarray(matches, dtype=float)
        except Exception:
            raise Refused(f"{field}.matches", "not a matrix of numbers")
        if m.ndim != 2:
            raise Refused(f"{field}.matches", f"not a matrix: {m.ndim} dimensions")
        shape = list(m.shape)
        if m.shape != (len(ids), len(targets)):
            # GenSim reads matches[i, j] for the objects i and targets j there are, and fails
            # only when it reaches a row or column that is not there: what is there is kept.
            fitted = np.zeros((len(ids), len(targets)))
            r, c = min(m.shape[0], len(ids)), min(m.shape[1], len(targets))
            fitted[:r, :c] = m[:r, :c]
            m = fitted
        else:
            shape = None
        zones = []
        if metric == 'zone':
            for k, z in enumerate(list(params)):
                zp = as_pose(z[0], f"{field}.params[{k}]")
                size = [float(s) for s in list(z[1])]
                zones.append([zp, size])
        elif metric != 'pose':
            raise Refused(f"{field}.metric", f"unknown metric {metric!r} (GenSim has 'pose' and 'zone')")
        if isinstance(language_goal, str):
            self.lang_goals.append(language_goal)
        elif isinstance(language_goal, list):
            self.lang_goals.extend(str(s) for s in language_goal)
        self.goals.append({'objs': ids, 'symmetries': syms, 'matches': m.tolist(),
                           'targets': targets, 'replace': bool(replace),
                           'rotations': bool(rotations), 'metric': metric, 'zones': zones,
                           'matches_shape': shape,
                           'step_max_reward': float(step_max_reward)})

    def make_piles(self, env, block_color=None, *a, **kw):
        ids = []
        for _ in range(int(self.num_blocks)):
            rx = self.bounds[0, 0] + 0.15 + np.random.rand() * 0.2
            ry = self.bounds[1, 0] + 0.4 + np.random.rand() * 0.2
            theta = np.random.rand() * 2 * np.pi
            oid = env.add_object('block/small.urdf', ((rx, ry, 0.01), quat_from_euler((0, 0, theta))))
            if block_color is not None:
                rgb, name = color_record(block_color)
                ENV.objects[oid - 1]['color'], ENV.objects[oid - 1]['color_name'] = rgb, name
            ENV.objects[oid - 1]['pile'] = True
            ids.append(oid)
        return ids

    def make_ropes(self, *a, **kw):
        raise Refused("make_ropes", "ropes are deformable: Assay simulates rigid bodies only")

    make_rope = make_ropes

    def add_corner_anchor_for_pose(self, env, pose):
        urdf = self.fill_template('corner/corner-template.urdf', {'DIMX': (0.04,), 'DIMY': (0.04,)})
        if len(pose) != 2:
            pose = [pose, (0, 0, 0, 1)]
        env.add_object(urdf, pose, 'fixed')

    def get_kitting_shapes(self, n_objects):
        if self.mode == 'train':
            return np.random.choice(self.train_set, n_objects)
        if self.homogeneous:
            return [np.random.choice(self.test_set)] * n_objects
        return np.random.choice(self.test_set, n_objects)

    def zip_obj_ids(self, obj_ids, symmetries):
        if isinstance(obj_ids[0], tuple):
            return obj_ids
        if symmetries is None:
            symmetries = [0.] * len(obj_ids)
        return [(o, (s, None)) for o, s in zip(obj_ids, symmetries)]

    def is_match(self, *a, **k):
        raise Refused("is_match", "evaluates a simulated state; reset() must not need it")

    def __getattr__(self, name):
        raise Refused(f"Task.{name}", "not part of the Ravens task API the recording provides")


def install():
    cl = types.ModuleType('cliport')
    tasks = types.ModuleType('cliport.tasks')
    task_mod = types.ModuleType('cliport.tasks.task')
    task_mod.Task = Task
    prim = types.ModuleType('cliport.tasks.primitives')
    prim.PickPlace = lambda *a, **k: 'pick-place'
    prim.push = 'push'
    grip = types.ModuleType('cliport.tasks.grippers')
    grip.Suction, grip.Spatula = 'suction', 'spatula'
    utils_pkg = types.ModuleType('cliport.utils')
    u = make_utils()
    utils_pkg.utils = u
    cl.tasks, cl.utils = tasks, utils_pkg
    tasks.task, tasks.primitives, tasks.grippers = task_mod, prim, grip
    return {'cliport': cl, 'cliport.tasks': tasks, 'cliport.tasks.task': task_mod,
            'cliport.tasks.primitives': prim, 'cliport.tasks.grippers': grip,
            'cliport.utils': utils_pkg, 'cliport.utils.utils': u, 'pybullet': make_pybullet(),
            'os': make_os()}


# ---------------------------------------------------------------------------------------------
# The sandbox.

# Modules task code may import: what GenSim tasks compute with. Anything else is refused.
ALLOWED = {'numpy', 'random', 'math', 'copy', 'itertools', 'functools', 'collections', 'typing',
           'string', 'dataclasses', 'enum', 'abc', 'operator', 'numbers', 'statistics', 'cmath',
           'decimal', 'fractions', 'heapq', 'bisect'}
# Modules that reach the world: importing one stops the process, whoever asks.
FORBIDDEN = {'subprocess', '_posixsubprocess', 'socket', '_socket', 'ssl', 'ctypes', '_ctypes',
             'multiprocessing', 'pty', 'webbrowser', 'ftplib', 'smtplib', 'sqlite3', 'mmap'}
STOP_EVENTS = ('os.system', 'os.exec', 'os.posix_spawn', 'os.spawn', 'os.fork', 'os.forkpty',
               'os.kill', 'os.killpg', 'os.remove', 'os.unlink', 'os.rename', 'os.rmdir',
               'os.mkdir', 'os.chmod', 'os.chown', 'os.truncate', 'os.symlink', 'os.link',
               'os.utime', 'os.putenv', 'os.unsetenv', 'os.chdir', 'subprocess.', 'socket.',
               'ctypes.', 'shutil.', 'signal.', 'sys.setrecursionlimit', 'pty.', 'fcntl.',
               'resource.', 'mmap.', 'sqlite3.', 'webbrowser.', 'sys.addaudithook',
               'sys.settrace', 'sys.setprofile', 'pickle.')
READ_ROOTS = []


def audit(event, args):
    if event == 'open':
        path, mode, flags = args[0], args[1], args[2]
        if isinstance(path, int):
            return
        writing = (mode is not None and any(c in str(mode) for c in 'wax+')) or \
                  (flags is not None and flags & (_os.O_WRONLY | _os.O_RDWR | _os.O_CREAT | _os.O_TRUNC))
        real = _os.path.realpath(_os.fsdecode(path)) if path is not None else ''
        if writing:
            _answer({'refused': {'field': 'open', 'reason': f"writes a file ({real}): task code "
                                 "may not write files"}}, 3)
        if not any(real == r or real.startswith(r + _os.sep) for r in READ_ROOTS):
            _answer({'refused': {'field': 'open', 'reason': f"reads {real}, outside the library "
                                 "(task code may read the library only)"}}, 3)
    elif event == 'import':
        top = str(args[0]).split('.')[0]
        if top in FORBIDDEN:
            _answer({'refused': {'field': 'import', 'reason': f"imports '{args[0]}': task code may "
                                 "not reach processes, sockets, signals, files or native code"}}, 3)
    elif event.startswith(STOP_EVENTS):
        _answer({'refused': {'field': event, 'reason': f"calls {event}: task code may not reach "
                             "processes, sockets, signals, files or the interpreter"}}, 3)


# Imports outside the allow-list the task made (stubbed: see Unused), and the first use of one
# (kept: code that catches the refusal is refused all the same).
STUBBED = []
USED = []


def allowed_text():
    return ', '.join(sorted(ALLOWED | {'os (os.path)', 'pybullet', 'cliport'}))


class Unused:
    """What an import outside the allow-list gives (a debugger, a plotting library left in the
    code): nothing at all. Reaching into it gives more of the same; using it — calling,
    iterating, indexing, testing, entering — refuses the task, naming the module and the use.
    No real module is loaded."""
    __slots__ = ('_name',)

    def __init__(self, name):
        object.__setattr__(self, '_name', name)

    def _refuse(self, what):
        name = object.__getattribute__(self, '_name')
        top = name.split('.')[0]
        refusal = Refused('import', f"imports '{top}' and uses {what}: task code may import only "
                                    f"{allowed_text()} (an import outside the list is stubbed, "
                                    "and refused where it is used)")
        if not USED:
            USED.append(refusal)
        raise refusal

    def __getattr__(self, attr):
        if attr.startswith('__') and attr.endswith('__'):
            raise AttributeError(attr)
        return Unused(f"{object.__getattribute__(self, '_name')}.{attr}")

    def __setattr__(self, attr, value):
        self._refuse(f"'{object.__getattribute__(self, '_name')}.{attr}' (set)")

    def __call__(self, *a, **k):
        self._refuse(f"'{object.__getattribute__(self, '_name')}(...)'")

    def __iter__(self):
        self._refuse(f"'{object.__getattribute__(self, '_name')}' (iterated)")

    def __getitem__(self, key):
        self._refuse(f"'{object.__getattribute__(self, '_name')}[...]'")

    def __enter__(self):
        self._refuse(f"'{object.__getattribute__(self, '_name')}' (with)")

    def __exit__(self, *a):
        return False

    def __bool__(self):
        self._refuse(f"'{object.__getattribute__(self, '_name')}' (tested)")

    def __len__(self):
        self._refuse(f"'{object.__getattribute__(self, '_name')}' (len)")

    def __index__(self):
        self._refuse(f"'{object.__getattribute__(self, '_name')}' (as a number)")

    __int__ = __float__ = __index__


def guarded_import(stand_ins):
    real_import = __import__

    def imp(name, globals=None, locals=None, fromlist=(), level=0):
        if level != 0:
            raise Refused('import', f"relative import of '{name}'")
        if name in stand_ins or name.split('.')[0] in ('cliport',):
            if name not in stand_ins:
                raise Refused('import', f"'{name}' is not part of the Ravens API the recording provides")
            mod = stand_ins[name]
            if fromlist:
                return mod
            return stand_ins[name.split('.')[0]]
        top = name.split('.')[0]
        if top not in ALLOWED:
            # Left in the code, unused (a debugger, plots): a stub, refused where it is used.
            if name not in STUBBED and len(STUBBED) < 50:
                STUBBED.append(str(name)[:100])
            return Unused(name if fromlist else top)
        return real_import(name, globals, locals, fromlist, level)
    return imp


def safe_builtins(stand_ins):
    import builtins
    b = dict(vars(builtins))
    for name in ('open', 'exec', 'eval', 'compile', 'input', 'breakpoint', '__loader__', 'exit',
                 'quit', 'help', 'copyright', 'credits', 'license', 'memoryview', 'globals',
                 'locals', 'vars'):
        b.pop(name, None)
    b['__import__'] = guarded_import(stand_ins)

    def no_open(*a, **k):
        raise Refused('open', "task code may not open files (the recording reads the assets itself)")
    b['open'] = no_open
    return b


def jsonable(x):
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if math.isfinite(v) else None
    if isinstance(x, (np.integer, int, bool)):
        return x if isinstance(x, bool) else int(x)
    return x if isinstance(x, (str, type(None))) else repr(x)[:200]


# ---------------------------------------------------------------------------------------------
# The OS boundary: what the kernel enforces under the guards above, set before the task's code is
# read. Neither can be undone by the process; both outlive anything the code finds (ctypes,
# numpy's C paths, a native library), and both hold where the Python guards do not.

# Landlock (linux/landlock.h): filesystem rights by ABI, TCP rights (ABI 4), scopes (ABI 6).
_LL_FS = {1: (1 << 13) - 1, 2: (1 << 14) - 1, 3: (1 << 15) - 1, 5: (1 << 16) - 1}
_LL_READ_FILE, _LL_READ_DIR = 1 << 2, 1 << 3
_LL_TCP = (1 << 0) | (1 << 1)            # bind, connect
_LL_SCOPES = (1 << 0) | (1 << 1)         # abstract UNIX sockets, signals outside the domain
_NR_LANDLOCK = (444, 445, 446)           # create_ruleset, add_rule, restrict_self: every arch
_PR_SET_NO_NEW_PRIVS, _PR_SET_SECCOMP, _SECCOMP_MODE_FILTER = 38, 22, 2

# seccomp: the system calls stopped, by architecture (audit arch, calls answered EPERM, clone,
# clone3). Processes (fork, vfork, clone without CLONE_THREAD: threads stay), program execution,
# sockets, tracing and other processes' memory, mounts and namespaces, kernel modules and
# keyrings, io_uring (which would bypass this filter), BPF, perf, and signals by pid.
_SECCOMP = {
    'x86_64': (0xC000003E, {
        'fork': 57, 'vfork': 58, 'execve': 59, 'execveat': 322, 'socket': 41, 'socketpair': 53,
        'ptrace': 101, 'process_vm_readv': 310, 'process_vm_writev': 311, 'mount': 165,
        'umount2': 166, 'pivot_root': 155, 'chroot': 161, 'unshare': 272, 'setns': 308,
        'bpf': 321, 'perf_event_open': 298, 'userfaultfd': 323, 'io_uring_setup': 425,
        'io_uring_enter': 426, 'io_uring_register': 427, 'keyctl': 250, 'add_key': 248,
        'request_key': 249, 'init_module': 175, 'finit_module': 313, 'delete_module': 176,
        'kexec_load': 246, 'kexec_file_load': 320, 'reboot': 169, 'swapon': 167, 'swapoff': 168,
        'acct': 163, 'settimeofday': 164, 'clock_settime': 227, 'open_by_handle_at': 304,
        'name_to_handle_at': 303, 'mknod': 133, 'mknodat': 259, 'kill': 62, 'pidfd_open': 434,
        'pidfd_send_signal': 424, 'pidfd_getfd': 438, 'personality': 135, 'iopl': 172,
        'ioperm': 173, 'fanotify_init': 300, 'open_tree': 428, 'move_mount': 429, 'fsopen': 430,
        'fsconfig': 431, 'fsmount': 432, 'fspick': 433, 'mount_setattr': 442}, 56, 435),
    'aarch64': (0xC00000B7, {
        'execve': 221, 'execveat': 281, 'socket': 198, 'socketpair': 199, 'ptrace': 117,
        'process_vm_readv': 270, 'process_vm_writev': 271, 'mount': 40, 'umount2': 39,
        'pivot_root': 41, 'chroot': 51, 'unshare': 97, 'setns': 268, 'bpf': 280,
        'perf_event_open': 241, 'userfaultfd': 282, 'io_uring_setup': 425, 'io_uring_enter': 426,
        'io_uring_register': 427, 'keyctl': 219, 'add_key': 217, 'request_key': 218,
        'init_module': 105, 'finit_module': 273, 'delete_module': 106, 'kexec_load': 104,
        'kexec_file_load': 294, 'reboot': 142, 'swapon': 224, 'swapoff': 225, 'acct': 89,
        'settimeofday': 170, 'clock_settime': 112, 'open_by_handle_at': 265,
        'name_to_handle_at': 264, 'mknodat': 33, 'kill': 129, 'pidfd_open': 434,
        'pidfd_send_signal': 424, 'pidfd_getfd': 438, 'personality': 92, 'fanotify_init': 262,
        'open_tree': 428, 'move_mount': 429, 'fsopen': 430, 'fsconfig': 431, 'fsmount': 432,
        'fspick': 433, 'mount_setattr': 442}, 220, 435),
}
# Where the shared libraries a lazily imported extension module needs may be read from.
SYSTEM_LIBS = ('/lib', '/lib64', '/usr/lib', '/usr/lib64', '/usr/local/lib', '/etc/ld.so.cache')


def _failed(call):
    """The OSError of a failed libc call (errno kept by ctypes)."""
    import ctypes
    e = ctypes.get_errno()
    return OSError(e, f'{call}: {_os.strerror(e)}')


def _landlock(libc, roots):
    """A Landlock domain: the roots (and system libraries) readable, nothing else readable or
    writable anywhere, no TCP, no abstract UNIX socket or signal outside it. Returns what it set,
    or raises OSError with why not."""
    import ctypes, errno, struct
    abi = libc.syscall(_NR_LANDLOCK[0], None, 0, 1)  # LANDLOCK_CREATE_RULESET_VERSION
    if abi < 1:
        e = ctypes.get_errno()
        raise OSError(e, 'Landlock is not enabled in this kernel' if e == errno.EOPNOTSUPP
                      else 'this kernel has no Landlock' if e == errno.ENOSYS
                      else f'Landlock: {_os.strerror(e)}')
    fs = _LL_FS[max(k for k in _LL_FS if k <= abi)]
    attr = struct.pack('<Q', fs)
    if abi >= 4:
        attr += struct.pack('<Q', _LL_TCP)
    if abi >= 6:
        attr += struct.pack('<Q', _LL_SCOPES)
    buf = ctypes.create_string_buffer(attr, len(attr))
    ruleset = libc.syscall(_NR_LANDLOCK[0], buf, ctypes.c_size_t(len(attr)), 0)
    if ruleset < 0:
        raise _failed('landlock_create_ruleset')
    try:
        readable = _landlock_rules(libc, ruleset, roots)
        if libc.prctl(_PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0) != 0:
            raise _failed('no_new_privs')
        if libc.syscall(_NR_LANDLOCK[2], ruleset, 0) < 0:
            raise _failed('landlock_restrict_self')
    finally:
        _os.close(ruleset)
    return (f"Landlock ABI {abi}: reads {len(readable)} folders (the library, the assets, Python, "
            "system libraries), writes nowhere" + (", no TCP" if abi >= 4 else "")
            + (", no abstract socket or signal outside" if abi >= 6 else ""))


def _landlock_rules(libc, ruleset, roots):
    """Each root readable (files: read; folders: read and list), as far as it exists."""
    import ctypes, struct
    readable = []
    for root in roots:
        try:
            fd = _os.open(root, _os.O_PATH | _os.O_CLOEXEC)
        except OSError:
            continue  # not on this machine
        try:
            access = _LL_READ_FILE | (_LL_READ_DIR if _os.path.isdir(root) else 0)
            rule = ctypes.create_string_buffer(struct.pack('<Qi', access, fd), 12)
            if libc.syscall(_NR_LANDLOCK[1], ruleset, 1, rule, 0) < 0:  # PATH_BENEATH
                raise _failed(f'landlock_add_rule {root}')
            readable.append(root)
        finally:
            _os.close(fd)
    return readable


def _seccomp(libc):
    """A seccomp filter that answers the calls of `_SECCOMP` with EPERM (clone3 with ENOSYS, so
    that threads are made by clone, whose flags a filter can read) and kills the process on a
    foreign ABI. Returns what it set, or raises OSError with why not."""
    import ctypes, errno, platform, struct
    machine = platform.machine()
    if machine not in _SECCOMP:
        raise OSError(errno.ENOSYS, f'no seccomp filter written for {machine}')
    arch, denied, clone, clone3 = _SECCOMP[machine]
    allow, kill = 0x7FFF0000, 0x80000000
    eperm, enosys = 0x00050000 | errno.EPERM, 0x00050000 | errno.ENOSYS
    # (code, k, jump-if-true label, jump-if-false label); labels resolve to relative offsets.
    prog = [(0x20, 4, None, None),                          # A = arch
            (0x15, arch, None, 'kill'),                     # foreign ABI: kill
            (0x20, 0, None, None)]                          # A = nr
    if machine == 'x86_64':
        prog.append((0x35, 0x40000000, 'eperm', None))     # x32 calls
    prog += [(0x15, clone, 'clone', None), (0x15, clone3, 'enosys', None)]
    prog += [(0x15, nr, 'eperm', None) for nr in sorted(set(denied.values()))]
    prog += [(0x06, allow, None, None),
             ('clone', 0x20, 16, None, None),               # A = low word of the flags
             (0x45, 0x00010000, 'allow', 'eperm'),          # CLONE_THREAD: a thread
             ('allow', 0x06, allow, None, None),
             ('eperm', 0x06, eperm, None, None),
             ('enosys', 0x06, enosys, None, None),
             ('kill', 0x06, kill, None, None)]
    labels, flat = {}, []
    for ins in prog:
        if isinstance(ins[0], str):
            labels[ins[0]] = len(flat)
            ins = ins[1:]
        flat.append(ins)
    code = b''
    for i, (op, k, jt, jf) in enumerate(flat):
        off = lambda label: 0 if label is None else labels[label] - i - 1
        code += struct.pack('<HBBI', op, off(jt), off(jf), k)

    class Prog(ctypes.Structure):
        _fields_ = [('len', ctypes.c_ushort), ('filter', ctypes.c_void_p)]
    filt = ctypes.create_string_buffer(code, len(code))
    fprog = Prog(len(flat), ctypes.cast(filt, ctypes.c_void_p))
    if libc.prctl(_PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0) != 0:
        raise _failed('no_new_privs')
    if libc.prctl(_PR_SET_SECCOMP, _SECCOMP_MODE_FILTER, ctypes.byref(fprog), 0, 0) != 0:
        raise _failed('seccomp')
    return (f"seccomp ({machine}): no processes, program execution, sockets, tracing, mounts, "
            f"namespaces, modules, io_uring or signals by pid ({len(denied) + 1} calls)")


def confine(roots):
    """Sets the OS boundary: {'landlock': ..., 'seccomp': ...}, each {'on': bool, 'note': str}."""
    import ctypes
    libc = ctypes.CDLL(None, use_errno=True)
    applied = {}
    for name, apply in (('landlock', lambda: _landlock(libc, list(roots) + list(SYSTEM_LIBS))),
                        ('seccomp', lambda: _seccomp(libc))):
        try:
            applied[name] = {'on': True, 'note': apply()}
        except (OSError, AttributeError, ValueError) as e:
            why = e.strerror if isinstance(e, OSError) and e.strerror else str(e)
            applied[name] = {'on': False, 'note': f"{why}"[:200]}
    return applied


ENV = None


def limit():
    """Hard limits, set before the task's code is read: they cannot be raised again."""
    import resource
    cpu = int(_os.environ.get('ASSAY_RECORDER_CPU_SECONDS', '20'))
    mem = int(_os.environ.get('ASSAY_RECORDER_MEMORY_BYTES', str(1 << 30)))
    # CPU: SIGXCPU at the soft limit ends the process; the hard one, a second later, is SIGKILL.
    resource.setrlimit(resource.RLIMIT_CPU, (cpu, cpu + 1))
    for res, value in ((resource.RLIMIT_AS, mem), (resource.RLIMIT_FSIZE, 0),
                       (resource.RLIMIT_CORE, 0), (resource.RLIMIT_NPROC, 0)):
        resource.setrlimit(res, (value, value))


def run_seed(cls, seed):
    """reset() of a fresh task on `seed`: what it built."""
    global ENV
    random.seed(seed)
    np.random.seed(seed)
    ENV = Env()
    TEMPLATES.clear()
    task = cls()
    ENV.task = task
    task.reset(ENV)
    return {
        'seed': seed, 'class': cls.__name__, 'objects': ENV.objects, 'goals': task.goals,
        'lang_goals': [str(s) for s in task.lang_goals],
        'lang_template': str(getattr(task, 'lang_template', '') or ''),
        'pos_eps': float(task.pos_eps), 'rot_eps': float(task.rot_eps),
        'ee': str(task.ee), 'primitive': str(task.primitive),
        'max_steps': jsonable(vars(task).get('max_steps')),
    }


def explain(e):
    """(field, reason) of what stopped a task's code."""
    if isinstance(e, Refused):
        return e.field, e.reason
    if isinstance(e, MemoryError):
        return 'reset', 'allocates beyond the memory limit'
    if isinstance(e, RecursionError):
        return 'reset', 'recursion too deep'
    tb = e.__traceback__
    line = None
    while tb is not None:
        if tb.tb_frame.f_code.co_filename == TASK_FILE:
            line = tb.tb_lineno
        tb = tb.tb_next
    where = f" (line {line})" if line else ''
    return 'reset', f"raised {type(e).__name__}: {e}"[:300] + where


def python_roots():
    """Where this Python and numpy live: what they read after the boundary is set."""
    roots = {_os.path.realpath(p) for p in
             (sys.prefix, sys.base_prefix, sys.exec_prefix, _os.path.dirname(np.__file__),
              _os.path.dirname(_os.__file__))}
    roots |= {_os.path.realpath(p) for p in sys.path if p}
    return sorted(roots)


def probe():
    """What the boundary gives here, for `assay doctor`: the limits, then the OS boundary."""
    limit()
    try:
        netns = _os.readlink('/proc/self/ns/net')
    except OSError:
        netns = None
    _answer({'boundary': confine(python_roots()), 'netns': netns})


def unguarded_builtins(stand_ins):
    """Test runs only: every builtin and every module, the Ravens stand-ins for cliport."""
    import builtins
    b = dict(vars(builtins))
    real_import = __import__

    def imp(name, globals=None, locals=None, fromlist=(), level=0):
        if name in stand_ins and name != 'os':
            return stand_ins[name] if fromlist else stand_ins[name.split('.')[0]]
        return real_import(name, globals, locals, fromlist, level)
    b['__import__'] = imp
    return b


def main():
    if PROBE:
        probe()
    limit()
    stand_ins = install()
    READ_ROOTS.extend([_os.path.realpath(LIBRARY), _os.path.realpath(ASSETS)] + python_roots())
    try:
        netns = _os.readlink('/proc/self/ns/net')
    except OSError:
        netns = None
    boundary = {} if NO_BOUNDARY else confine(READ_ROOTS)
    with open(TASK_FILE, 'rb') as f:
        source = f.read()
    try:
        code = compile(source, TASK_FILE, 'exec')
    except SyntaxError as e:
        _answer({'refused': {'field': 'code', 'reason': f"not Python: {e.msg} (line {e.lineno})"}})
    if UNGUARDED:
        builtins = unguarded_builtins(stand_ins)
    else:
        sys.addaudithook(audit)
        builtins = safe_builtins(stand_ins)
    module = {'__name__': 'gensim_task', '__file__': _os.path.basename(TASK_FILE),
              '__builtins__': builtins}
    seeds = []
    try:
        exec(code, module)
        classes = [c for c in module.values()
                   if isinstance(c, type) and issubclass(c, Task) and c is not Task]
        if not classes:
            raise Refused('code', 'no subclass of cliport.tasks.task.Task')
        cls = classes[-1]
        for k, seed in enumerate(SEEDS):
            try:
                seeds.append(run_seed(cls, seed))
            except (Refused, MemoryError, RecursionError, Exception) as e:
                # The first seed is the task's: it fails the task. Another seed fails alone.
                if k == 0:
                    raise
                field, reason = explain(e)
                seeds.append({'seed': seed, 'refused': {'field': field, 'reason': reason}})
    except BaseException as e:
        field, reason = explain(e)
        _answer({'refused': {'field': field, 'reason': reason}})
    if USED:
        _answer({'refused': {'field': USED[0].field, 'reason': USED[0].reason}})
    _answer({'seeds': jsonable(seeds), 'stubbed': list(STUBBED), 'netns': netns,
             'boundary': boundary})


if __name__ == '__main__':
    try:
        main()
    except BaseException as e:  # the recorder's own failure, before the task ran
        _answer({'error': f"{type(e).__name__}: {e}"[:300]}, 2)
