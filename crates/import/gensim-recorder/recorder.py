"""PROTOTYPE, not wired into `assay import gensim` yet (issue 25 groundwork).

Runs a GenSim task's reset() against a recording stand-in of the Ravens API (Task, env,
utils, pybullet) and prints what it built as JSON: objects with URDF, pose, colour and category,
filled templates with their replacement dicts, and goals with matches, target poses and metric.
No simulator, no pybullet, nothing written. Measured on ../shared/corpora/gensim-library (numpy
2.4 from PyPI): reset() runs for 93 of the 96 task files on each of seeds 0-4; the other 3 build
ropes, refused as deformable.

Not done here, and needed before the importer may call it: the sandbox (rlimits on CPU time
and address space, a wall-clock timeout, an audit hook refusing os/subprocess/socket and file
writes, a read-only view of the library), the translation of its records into spec v1, and
tests. Usage: python recorder.py TASK.py SEED"""
import json, math, random, sys, types, importlib.util
from collections import defaultdict
import numpy as np


class Unsupported(Exception):
    pass


def quat_from_euler(r):
    # xyz euler (roll, pitch, yaw) -> xyzw, fixed axes (pybullet's convention)
    cx, sx = math.cos(r[0] / 2), math.sin(r[0] / 2)
    cy, sy = math.cos(r[1] / 2), math.sin(r[1] / 2)
    cz, sz = math.cos(r[2] / 2), math.sin(r[2] / 2)
    return (sx * cy * cz - cx * sy * sz, cx * sy * cz + sx * cy * sz,
            cx * cy * sz - sx * sy * cz, cx * cy * cz + sx * sy * sz)


def euler_from_quat(q):
    x, y, z, w = q
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1, min(1, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return (roll, pitch, yaw)


def rot_matrix(q):
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


class Env:
    def __init__(self):
        self.objects = []
        self.obj_ids = {'fixed': [], 'rigid': [], 'deformable': []}

    def add_object(self, urdf, pose, category='rigid', color=None, **kw):
        oid = len(self.objects) + 1
        pos = [float(v) for v in pose[0]]
        rot = [float(v) for v in pose[1]]
        if color is not None and not isinstance(color, str):
            color = [float(c) for c in list(color)[:3]]
        self.objects.append({'id': oid, 'urdf': urdf, 'pose': [pos, rot],
                             'category': category, 'color': color})
        self.obj_ids.setdefault(category, []).append(oid)
        return oid

    def __getattr__(self, name):
        raise Unsupported(f'env.{name}')


ENV = None
TEMPLATES = []


def make_pybullet():
    p = types.ModuleType('pybullet')

    def get_pose(oid):
        o = ENV.objects[oid - 1]
        return tuple(o['pose'][0]), tuple(o['pose'][1])

    def change_visual(oid, link=-1, rgbaColor=None, **kw):
        if rgbaColor is not None:
            ENV.objects[oid - 1]['color'] = [float(c) for c in list(rgbaColor)[:3]]

    p.getBasePositionAndOrientation = get_pose
    p.changeVisualShape = change_visual
    p.stepSimulation = lambda *a, **k: None
    p.getQuaternionFromEuler = quat_from_euler
    p.getEulerFromQuaternion = euler_from_quat
    p.getMatrixFromQuaternion = lambda q: tuple(rot_matrix(q).flatten())

    def missing(name):
        raise Unsupported(f'pybullet.{name}')
    p.__getattr__ = missing
    return p


def make_utils():
    u = types.ModuleType('cliport.utils.utils')
    colors = {
        'blue': [78 / 255, 121 / 255, 167 / 255], 'red': [255 / 255, 87 / 255, 89 / 255],
        'green': [89 / 255, 169 / 255, 78 / 255], 'orange': [242 / 255, 142 / 255, 43 / 255],
        'yellow': [237 / 255, 201 / 255, 72 / 255], 'purple': [176 / 255, 122 / 255, 161 / 255],
        'pink': [255 / 255, 157 / 255, 167 / 255], 'cyan': [118 / 255, 183 / 255, 178 / 255],
        'brown': [156 / 255, 117 / 255, 95 / 255], 'white': [1.0, 1.0, 1.0],
        'gray': [186 / 255, 176 / 255, 172 / 255], 'indigo': [75 / 255, 0, 130 / 255],
        'violet': [143 / 255, 0, 1.0], 'black': [0.0, 0.0, 0.0],
        'silver': [192 / 255, 192 / 255, 192 / 255], 'gold': [1.0, 215 / 255, 0.0]}
    u.COLORS = defaultdict(lambda: [1.0, 0.0, 0.0], colors)
    u.COLORS_NAMES = list(colors)
    u.TRAIN_COLORS = ['blue', 'red', 'green', 'yellow', 'brown', 'gray', 'cyan']
    u.EVAL_COLORS = ['blue', 'red', 'green', 'orange', 'purple', 'pink', 'white']

    def get_colors(mode, n_colors=-1, **kw):
        names = u.TRAIN_COLORS if n_colors == -1 else random.sample(u.TRAIN_COLORS, n_colors)
        return [u.COLORS[c] for c in names], names
    u.get_colors = get_colors
    u.get_random_color = lambda: get_colors('train', 1)
    u.eulerXYZ_to_quatXYZW = quat_from_euler
    u.quatXYZW_to_eulerXYZ = euler_from_quat

    def apply(pose, position):
        position = np.float32(position)
        shape = position.shape
        position = position.reshape(3, -1)
        out = rot_matrix(pose[1]).astype(np.float32) @ position + np.float32(pose[0]).reshape(3, 1)
        return tuple(out.reshape(shape))
    u.apply = apply

    def multiply(a, b):
        r = rot_matrix(a[1])
        t = tuple(r @ np.array(b[0]) + np.array(a[0]))
        # quaternion product a*b (xyzw)
        x1, y1, z1, w1 = a[1]
        x2, y2, z2, w2 = b[1]
        q = (w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2, w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
             w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2, w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2)
        return t, q
    u.multiply = multiply
    u.map_kit_scale = lambda s: (s[0] / 10, s[1] / 10, s[2] / 10)
    u.assembling_kit_shapes = {i: n for i, n in enumerate([
        "letter R shape", "letter A shape", "triangle", "square", "plus", "letter T shape",
        "diamond", "pentagon", "rectangle", "flower", "star", "circle", "letter G shape",
        "letter V shape", "letter E shape", "letter L shape", "ring", "hexagon", "heart",
        "letter M shape"])}

    def missing(name):
        raise Unsupported(f'utils.{name}')
    u.__getattr__ = missing
    return u


class Task:
    def __init__(self):
        self.ee = 'suction'
        self.mode = 'train'
        self.sixdof = False
        self.primitive = None
        self.pos_eps = 0.01
        self.rot_eps = np.deg2rad(15)
        self.num_blocks = 50
        self.pix_size = 0.003125
        self.bounds = np.array([[0.25, 0.75], [-0.5, 0.5], [0, 0.3]])
        self.zone_bounds = np.copy(self.bounds)
        self.goals = []
        self.lang_goals = []
        self.task_completed_desc = 'task completed.'
        self.assets_root = None
        self.homogeneous = False
        self.lang_template = ''

    def reset(self, env):
        self.goals = []
        self.lang_goals = []

    def additional_reset(self):
        pass

    def get_random_pose(self, env, obj_size=0.1, **kw):
        if np.isscalar(obj_size):
            obj_size = (obj_size, obj_size, obj_size)
        radius = math.sqrt(obj_size[0] ** 2 + obj_size[1] ** 2) / 2
        placed = [(o['pose'][0], o.get('radius', 0.03)) for o in env.objects]
        for _ in range(200):
            x = np.random.uniform(self.bounds[0, 0] + radius, self.bounds[0, 1] - radius)
            y = np.random.uniform(self.bounds[1, 0] + radius, self.bounds[1, 1] - radius)
            if all(math.hypot(x - q[0], y - q[1]) > radius + r for q, r in placed):
                break
        z = obj_size[2] / 2 if len(obj_size) > 2 else 0.05
        theta = np.random.rand() * 2 * np.pi
        return [float(x), float(y), float(z)], quat_from_euler((0, 0, theta))

    def fill_template(self, template, replace):
        TEMPLATES.append({'template': template,
                          'replace': {k: (v if isinstance(v, str) else
                                          [x if isinstance(x, str) else float(x) for x in v])
                                      for k, v in replace.items()}})
        return f'assay-template:{len(TEMPLATES) - 1}'

    def get_random_size(self, min_x, max_x, min_y, max_y, min_z, max_z):
        s = np.random.rand(3)
        return (s[0] * (max_x - min_x) + min_x, s[1] * (max_y - min_y) + min_y,
                s[2] * (max_z - min_z) + min_z)

    def add_goal(self, objs, matches, targ_poses, replace, rotations, metric, params,
                 step_max_reward, symmetries=None, language_goal=None, **kw):
        def oid(o):
            return int(o[0]) if isinstance(o, (tuple, list)) else int(o)
        poses = []
        for t in targ_poses:
            poses.append([[float(v) for v in t[0]], [float(v) for v in t[1]]]
                         if isinstance(t, (tuple, list)) and len(t) == 2 else repr(t))
        self.goals.append({'objs': [oid(o) for o in objs],
                           'matches': np.asarray(matches).astype(float).tolist(),
                           'targ_poses': poses, 'replace': bool(replace),
                           'rotations': bool(rotations), 'metric': metric,
                           'params': repr(params), 'symmetries': symmetries})
        if isinstance(language_goal, str):
            self.lang_goals.append(language_goal)
        elif isinstance(language_goal, list):
            self.lang_goals.extend(language_goal)

    def make_piles(self, env, block_color=None, *a, **kw):
        ids = []
        for _ in range(self.num_blocks):
            rx = self.bounds[0, 0] + 0.15 + np.random.rand() * 0.2
            ry = self.bounds[1, 0] + 0.4 + np.random.rand() * 0.2
            ids.append(env.add_object('block/small.urdf',
                                      ((rx, ry, 0.01), quat_from_euler((0, 0, 0))),
                                      color=block_color))
        return ids

    def make_ropes(self, *a, **kw):
        raise Unsupported('ropes are deformable')

    make_rope = make_ropes

    def add_corner_anchor_for_pose(self, env, pose):
        urdf = self.fill_template('corner/corner-template.urdf', {'DIMX': (0.04,), 'DIMY': (0.04,)})
        if len(pose) != 2:
            pose = [pose, (0, 0, 0, 1)]
        env.add_object(urdf, pose, 'fixed')

    def get_kitting_shapes(self, n_objects):
        shapes = list(range(20)) if self.mode == 'train' else [0] * 20
        return np.random.choice(shapes, n_objects, replace=False)

    def __getattr__(self, name):
        raise Unsupported(f'Task.{name}')


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
    for name, m in [('cliport', cl), ('cliport.tasks', tasks), ('cliport.tasks.task', task_mod),
                    ('cliport.tasks.primitives', prim), ('cliport.tasks.grippers', grip),
                    ('cliport.utils', utils_pkg), ('cliport.utils.utils', u),
                    ('pybullet', make_pybullet())]:
        sys.modules[name] = m


def run(path, seed):
    global ENV
    install()
    spec = importlib.util.spec_from_file_location('gensim_task', path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    classes = [c for c in vars(mod).values()
               if isinstance(c, type) and issubclass(c, Task) and c is not Task]
    if not classes:
        raise Unsupported('no Task subclass')
    random.seed(seed)
    np.random.seed(seed)
    ENV = Env()
    TEMPLATES.clear()
    task = classes[-1]()
    task.assets_root = 'assets'
    task.reset(ENV)
    return {'class': classes[-1].__name__, 'objects': ENV.objects, 'templates': list(TEMPLATES),
            'goals': task.goals, 'lang_goals': task.lang_goals}


if __name__ == '__main__':
    try:
        print(json.dumps({'ok': run(sys.argv[1], int(sys.argv[2]))}))
    except Unsupported as e:
        print(json.dumps({'unsupported': str(e)}))
    except Exception as e:
        print(json.dumps({'error': f'{type(e).__name__}: {e}'}))
