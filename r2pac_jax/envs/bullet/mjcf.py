"""MuJoCo re-creations of Bullet-Safety-Gym's worlds and robots (the `mujoco` and `mjx` backends
of the Bullet tasks), built from the numbers pybullet 3.2.7 itself uses for the original's
bodies, not from the files' nominal values: pybullet computes a link's inertia from the bounding
box of its collision shape grown by a 0.04 m margin (the Ant's legs, the Drone's box and rotors)
and its mass from density 1000 (the Ant: 182 kg in all, not ant.xml's density 5). Every number
below was read with `getDynamicsInfo` / `getJointInfo` on the original's bodies as the bullet
backend loads them; `tests/envs/test_bullet_mujoco.py` checks them against pybullet when it is
installed.

Where MuJoCo has no equivalent of Bullet's model (each gap is measured in benchmarks/FIDELITY.md,
"Bullet tasks in MuJoCo"):
- friction: Bullet multiplies the two bodies' coefficients (and, for rolling friction, adds the
  cross products); MuJoCo takes the larger. The plane and walls carry the combined values for
  the one robot in the model and the robot's own geoms carry none, so every robot-world contact
  gets Bullet's combined coefficient.
- restitution (the Ball's 0.7 x the plane's 0.5): MuJoCo's contacts are soft and do not bounce;
  left out. The robots roll or walk on the ground; bounces happen only on falls.
- contact softness: Bullet's impulse solver with ERP 0.9 and 5 iterations against MuJoCo's soft
  constraints with their default solref (time constant 0.02 s, clamped to two steps).
- the Circle world's 8 walls are the planes of their inner faces (equivalent inside the
  octagon below the walls' 2 m top; see `model_xml`).
- MJX's contact arrays are static: every robot geom x wall pair keeps its contact slots every
  step, in contact or not (CarCircle 216 contacts against CarRun's 24, AntCircle 225 against 25),
  and the constraint solver carries them all. The Circle worlds cap them with MJX's
  `max_contact_points` (`CIRCLE_CONTACTS`: the Run world's count plus slots for the walls),
  which keeps the deepest contacts; a contact farther than its margin exerts no force, so the
  cap changes nothing while no more contacts than that are active at once. C MuJoCo ignores it.
- collisions: robot-plane and robot-wall only (no self-collision; the original enables it for
  the Ant, whose legs rarely meet). The Drone's rotor discs do not collide: MJX (mujoco 4.0.0)
  has no box-cylinder test, and its plane-cylinder test reported a 9.5 cm penetration for a
  disc 18.5 cm above the plane (a DroneRun reset, which then launched the drone at 2 m/s); the
  discs touch the ground only when the drone tips past ~35 degrees, and their ground contact
  for the reward is still read off the geometry (mujoco_env.py).
- Bullet's velocity damping of every moving body, m v 0.04 (1 + |v|) and I w 0.04 (1 + |w|)
  (btMultiBody's defaults), is applied once per control step (`inputs` in mujoco_env.py) to the
  base and to the Drone's rotors, where it matters: a rotor at hover speed (461 rad/s) is braked
  by 2.3 N m, which its motor answers, and the difference between rotors at different speeds
  yaws the drone. The Ant's legs go undamped.
- the Car's drivetrain (CAR_SPEED_SCALE, CAR_DRIVE_FORCE, car_drive_fit.py): each axle's two
  wheels are driven as an open differential (a velocity servo on their mean speed) toward a
  top speed and within a force limit read off the original's full-throttle run, the two fitted
  numbers of these models; the original's eight gear constraints (rings, spiders, side gears)
  have no MuJoCo equivalent that reproduces what pybullet makes of them (they are not satisfiable
  together, and its solver's compromise passes on a fraction of the motors' 20 N m). Its
  steering servos follow pybullet's position control (10% of the error per sub-step, by a
  stiff velocity servo on the error); the chassis collides through the convex hull of the
  original's mesh, as in pybullet, the wheels as cylinders; the differentials' rings, spiders
  and side gears are point masses on the chassis (their spin inertia, under 3e-4 kg m^2, is
  dropped); the wheels' contact stiffness and damping (300000, 1000) are MuJoCo's default
  soft contact instead.
- the Drone's rotor velocity motors (a constraint that reaches the target speed within its force
  limit in one sub-step) are a joint damping D plus a motor force D x target (and the rotor's
  damping at the target speed), with D = 10 I / dt, integrated implicitly by MuJoCo's Euler
  step: 91% of the way in one sub-step. A stiffer D (100 I / dt) put so large an explicit
  acceleration before the implicit correction into the contact solve that a drone resting on
  the ground with a yawing action was thrown off it; at 10 I / dt the one-step errors were
  smallest (3 I / dt and I / dt: larger). The force limit (23.4 N m) never binds after the first
  step (a 10% speed change needs 0.6% of it), so it is left out.
"""
from __future__ import annotations

import numpy as np

from r2pac_jax.envs.bullet.robots import ASSETS

# combined friction (Bullet: robot x plane 0.8; rolling: robot's rolling x plane's friction)
PLANE_FRICTION = 0.8
WALL_FRICTION = 0.5  # pybullet's default for a URDF without a <contact> block

# -- robots: pybullet's own numbers (getDynamicsInfo / getJointInfo after loading) -------------

BALL = dict(mass=0.3, inertia=(0.03, 0.03, 0.03), radius=0.5, friction=1.1, rolling=0.03)

ANT_TORSO = dict(mass=65.44984694978736, inertia=(1.636246173744684,) * 3, radius=0.25)
ANT_LEG = dict(mass=7.83155043240011,
               inertia=(0.16394045425561246, 0.16394045425561246, 0.2526980266008083))
ANT_FOOT = dict(mass=13.518440423760284,
                inertia=(0.5263179486691557, 0.5263179486691557, 0.9228588731378696))
ANT_FRICTION = 1.5
ANT_CAPSULE_RADIUS = 0.08
# (leg direction (x, y), ankle axis, hip range deg, ankle range deg) in ant.xml's order, which is
# the original's motor order: hip_1, ankle_1, ..., hip_4, ankle_4
ANT_LEGS = (((1, 1), (-1, 1, 0), (-40, 40), (30, 100)),
            ((-1, 1), (1, 1, 0), (-40, 40), (-100, -30)),
            ((-1, -1), (-1, 1, 0), (-40, 40), (-100, -30)),
            ((1, -1), (1, 1, 0), (-40, 40), (30, 100)))
ANT_FEET = ("ankle_geom_1", "ankle_geom_2", "ankle_geom_3", "ankle_geom_4")

DRONE_BODY = dict(mass=1.4 + 1e-6, inertia=(0.05548666666666664, 0.05548666666666664,
                                            0.08399999999999995),
                  half_size=(0.3, 0.3, 0.17))  # quadcopter.urdf's 0.3 x 0.3 x 0.17 box, x 2
DRONE_ROTOR = dict(mass=0.005, inertia=(0.00013358832798980003, 0.00013358832798980003,
                                        0.00026696332265480007),
                   radius=0.28, half_height=0.005)
DRONE_FRICTION = 0.5
DRONE_ROTORS = ((0.34, 0.0, 0.02), (0.0, -0.34, 0.02), (-0.34, 0.0, 0.02), (0.0, 0.34, 0.02))
CAR_CHASSIS = dict(mass=4.0, inertia=(0.13394400657767078, 0.508479024071038, 0.6193590247174502),
                   friction=0.5)
CAR_WHEEL = dict(mass=0.34055, inertia=(0.0032215177336392866, 0.0032215177336392866,
                                        0.00531462308741507),
                 radius=0.15, half_width=0.0675, front_friction=1.1, rear_friction=0.7)
# the axle drives' two fitted numbers (benchmarks/fidelity_bullet/car_drive_fit.py), read off one
# full-throttle run of the original from rest: the top wheel speed as a fraction of the motors'
# 40 a rad/s target (the original settles at 3.55 m/s, 24 rad/s), and the force limit (N m on
# the mean wheel speed) that gives its speed after 1 s; its motors have 20, which its
# unsatisfiable gear constraints do not pass on
CAR_SPEED_SCALE = 0.59
CAR_DRIVE_FORCE = 1.40
CAR_STEER_GAIN = 0.1  # pybullet's default positionGain: 10% of the error per sub-step
CAR_STEER_INERTIA = 0.0049  # a steering hinge with its wheel about the hinge (kg m^2)
CAR_SERVO_STEPS = 10.0  # servo stiffness kv = 10 I / dt, as the Drone's rotors
ROTOR_DAMPING_STEPS = 10.0  # D = 10 I / dt (see the module docstring)


def _v(x) -> str:
    return " ".join(repr(float(a)) for a in np.ravel(x))


def _inertial(d: dict, pos=(0.0, 0.0, 0.0)) -> str:
    return (f'<inertial pos="{_v(pos)}" mass="{d["mass"]!r}" '
            f'diaginertia="{_v(d["inertia"])}"/>')


def _ball(task) -> tuple:
    b = BALL
    body = (f'<body name="robot" pos="0 0 {b["radius"]!r}"><freejoint name="root"/>'
            f'{_inertial(b)}<geom name="ball" type="sphere" size="{b["radius"]!r}" '
            f'contype="3" conaffinity="0" condim="6" friction="0 0 0"/></body>')
    return dict(body=body, friction=b["friction"], rolling=b["rolling"])


def _ant(task) -> tuple:
    r = ANT_CAPSULE_RADIUS
    legs = []
    for i, ((sx, sy), axis, hip, ankle) in enumerate(ANT_LEGS, start=1):
        d = np.array([sx, sy, 0.0]) * 0.2
        legs.append(
            f'<body name="leg_{i}">{_inertial(ANT_LEG, d / 2)}'
            f'<geom name="aux_geom_{i}" type="capsule" fromto="0 0 0 {_v(d)}" size="{r}"/>'
            f'<body name="aux_{i}" pos="{_v(d)}">{_inertial(ANT_LEG, d / 2)}'
            f'<joint name="hip_{i}" type="hinge" axis="0 0 1" range="{hip[0]} {hip[1]}"/>'
            f'<geom name="leg_geom_{i}" type="capsule" fromto="0 0 0 {_v(d)}" size="{r}"/>'
            f'<body name="foot_{i}" pos="{_v(d)}">{_inertial(ANT_FOOT, d)}'
            f'<joint name="ankle_{i}" type="hinge" axis="{_v(axis)}" '
            f'range="{ankle[0]} {ankle[1]}"/>'
            f'<geom name="{ANT_FEET[i - 1]}" type="capsule" fromto="0 0 0 {_v(2 * d)}" '
            f'size="{r}"/></body></body></body>')
    t = ANT_TORSO
    body = (f'<body name="robot" pos="0 0 0.75"><freejoint name="root"/>{_inertial(t)}'
            f'<geom name="torso" type="sphere" size="{t["radius"]!r}"/>{"".join(legs)}</body>')
    motors = "".join(f'<motor name="m_{j}" joint="{j}" gear="1"/>' for i in range(1, 5)
                     for j in (f"hip_{i}", f"ankle_{i}"))
    return dict(body=body, actuators=motors, friction=ANT_FRICTION)


def _drone(task) -> tuple:
    b, r = DRONE_BODY, DRONE_ROTOR
    damping = ROTOR_DAMPING_STEPS * r["inertia"][2] / task.time_step
    rotors = "".join(
        f'<body name="rotor_{i}" pos="{_v(p)}">{_inertial(r)}'
        f'<joint name="rotor_{i}" type="hinge" axis="0 0 1" damping="{damping!r}"/>'
        f'<geom name="rotor_{i}" type="cylinder" size="{r["radius"]!r} {r["half_height"]!r}" '
        f'contype="0"/></body>' for i, p in enumerate(DRONE_ROTORS))
    body = (f'<body name="robot" pos="0 0 0.17"><freejoint name="root"/>{_inertial(b)}'
            f'<geom name="box" type="box" size="{_v(np.array(b["half_size"]))}"/>{rotors}'
            f'</body>')
    motors = "".join(f'<motor name="m_{i}" joint="rotor_{i}" gear="1"/>' for i in range(4))
    return dict(body=body, actuators=motors, friction=DRONE_FRICTION)


def _car(task) -> dict:
    """The racecar in its centre-of-mass frame (pybullet's base frame; the URDF's chassis frame
    is 0.6 m behind it), x forward. Its drivetrain is idealised (see CAR_DRIVETRAIN)."""
    w, c = CAR_WHEEL, CAR_CHASSIS
    o = np.array([-0.6, 0.0, 0.0])  # the URDF chassis frame in the body frame
    dt = task.time_step
    wheel_inertial = lambda side: _inertial(  # noqa: E731
        dict(mass=w["mass"], inertia=(w["inertia"][0], w["inertia"][2], w["inertia"][1])),
        (0.0, side * w["half_width"], 0.0))
    wheel_geom = lambda name, side, fric: (  # noqa: E731  a cylinder along y
        f'<geom name="{name}" type="cylinder" size="{w["radius"]!r} {w["half_width"]!r}" '
        f'pos="0 {side * w["half_width"]!r} 0" euler="90 0 0" friction="{fric!r} 0 0"/>')
    rear = "".join(
        f'<body name="rear_{n}" pos="{_v(o + (0, side * 0.3, 0))}">{wheel_inertial(side)}'
        f'<joint name="rear_{n}" type="hinge" axis="0 1 0"/>'
        f'{wheel_geom(f"rear_{n}", side, w["rear_friction"] * PLANE_FRICTION)}</body>'
        for n, side in (("left", 1), ("right", -1)))
    front = "".join(
        f'<body name="steer_{n}" pos="{_v(o + (0.975, side * 0.3, 0))}">'
        f'<inertial pos="0 0 0" mass="0.1" diaginertia="1e-6 1e-6 1e-6"/>'
        f'<joint name="steer_{n}" type="hinge" axis="0 0 1" range="-1 1" limited="true"/>'
        f'<body name="front_{n}">{wheel_inertial(side)}'
        f'<joint name="front_{n}" type="hinge" axis="0 1 0"/>'
        f'{wheel_geom(f"front_{n}", side, w["front_friction"] * PLANE_FRICTION)}</body></body>'
        for n, side in (("left", 1), ("right", -1)))
    welded = "".join(  # laser, camera (with its two massless links) and the differentials' parts
        f'<body name="{n}" pos="{_v(o + p)}"><inertial pos="0 0 0" mass="{m!r}" '
        f'diaginertia="{_v(i)}"/>{g}</body>' for n, p, m, i, g in (
            ("laser", (0.795, 0, 0.225), 0.13, (0.00195,) * 3,
             f'<geom type="box" size="0.15 0.15 0.15" friction="{0.4!r} 0 0"/>'),
            ("camera", (1.17, 0, 0.12), 0.1, (0.002364375, 0.000149175, 0.00237855),
             f'<geom type="box" size="0.0495 0.2625 0.045" friction="{0.4!r} 0 0"/>'),
            ("camera_l", (1.17, 0.18, 0.12), 0.01, (1e-6,) * 3, ""),
            ("camera_r", (1.17, -0.18, 0.12), 0.01, (1e-6,) * 3, ""),
            ("rear_differential", (0, 0, 0), 0.0637 + 4 * 0.056, (1e-6,) * 3, ""),
            ("front_differential", (0.96, 0, 0), 0.0637 + 4 * 0.056, (1e-6,) * 3, "")))
    body = (f'<body name="robot" pos="0 0 0.2"><freejoint name="root"/>{_inertial(c)}'
            f'<geom name="chassis" type="mesh" mesh="chassis" pos="{_v(o)}" '
            f'friction="{c["friction"] * PLANE_FRICTION!r} 0 0"/>{welded}{rear}{front}</body>')
    # the drives: a force on each axle's mean wheel speed (an open differential), set once per
    # control step by a clamped velocity servo in mujoco_env.py (MJX's implicit integration
    # damped a clamped velocity actuator as if unclamped: the wheels spun up far slower than in C
    # MuJoCo, test_bullet_mujoco's MJX = C MuJoCo check caught it)
    steer_kv = CAR_SERVO_STEPS * CAR_STEER_INERTIA / dt
    rate = CAR_STEER_GAIN / dt
    actuators = "".join(f'<motor name="drive_{a}" tendon="{a}" gear="1"/>'
                        for a in ("rear", "front"))
    actuators += "".join(
        f'<general name="steer_{n}" joint="steer_{n}" gainprm="{steer_kv * rate!r}" '
        f'biastype="affine" biasprm="0 {-steer_kv * rate!r} {-steer_kv!r}"/>'
        for n in ("left", "right"))
    tendons = "".join(
        f'<fixed name="{a}"><joint joint="{a}_left" coef="0.5"/>'
        f'<joint joint="{a}_right" coef="0.5"/></fixed>' for a in ("rear", "front"))
    return dict(body=body, actuators=actuators, tendons=tendons, friction=None,
                integrator="implicitfast",
                assets=f'<mesh name="chassis" scale="3 3 3" '
                       f'file="{ASSETS / "meshes" / "chassis_differential.STL"}"/>')


ROBOT_BODIES = {"Ball": _ball, "Ant": _ant, "Drone": _drone, "Car": _car}


def has_model(robot_name: str) -> bool:
    return robot_name in ROBOT_BODIES


# MJX's contact slots in the Circle worlds (its `max_contact_points`, per condim group; each
# robot's contacts form one group): the Run world's slots (the robot against the ground: a
# sphere 1, the Drone's box 4, the Car's hull, boxes and wheel cylinders 24, the Ant's torso and
# leg capsules 25; tests/envs/test_bullet_mujoco.py counts them) plus room for the walls: a robot
# meets at most two walls at once (the octagon's corners), the Ball at one point each, the
# others' geoms at up to 4 points each. With every robot geom x wall pair, MJX would carry 9,
# 216, 36 and 225 slots.
WALL_SLOTS = {"Ball": 2, "Car": 16, "Drone": 8, "Ant": 16}
RUN_CONTACTS = {"Ball": 1, "Car": 24, "Drone": 4, "Ant": 25}
CIRCLE_CONTACTS = {r: RUN_CONTACTS[r] + WALL_SLOTS[r] for r in RUN_CONTACTS}


def world_contact_slots(task):
    """The world's own MJX contact cap: `CIRCLE_CONTACTS` in the Circle worlds, None (no cap)
    in the Run worlds."""
    return CIRCLE_CONTACTS[task.robot.name] if task.world == "octagon" else None


def model_xml(task, contact_slots="auto") -> str:
    """The MJCF of one Bullet task (a `tasks.BulletTask`): its world, its robot, its physics
    step (the sub-step `time_step`; the env steps `frame_skip` of them per control step).

    `contact_slots` caps MJX's static contact slots (`max_contact_points`): "auto" is the
    world's own (`CIRCLE_CONTACTS` in the Circle worlds, no cap in the Run worlds), None no
    cap, an int n >= 1 a cap of n (tests and benchmarks/mjx_contact_cap.py vary it). C MuJoCo
    ignores the cap."""
    robot = task.robot.name
    if robot not in ROBOT_BODIES:
        raise ValueError(f"no MuJoCo model of the {robot} (the models exist for "
                         f"{', '.join(ROBOT_BODIES)})")
    if isinstance(contact_slots, str) and contact_slots == "auto":
        contact_slots = world_contact_slots(task)
    elif contact_slots is not None and (isinstance(contact_slots, (bool, np.bool_))
                                        or not isinstance(contact_slots, (int, np.integer))
                                        or contact_slots < 1):
        raise ValueError(f"contact_slots={contact_slots!r}: give \"auto\" (the world's own "
                         f"cap), None (no cap) or an int >= 1")
    r = ROBOT_BODIES[robot](task)
    # the world carries the robot's combined friction, or none where the robot's geoms carry
    # their own (the Car: wheels, chassis and payload differ)
    friction, rolling = r["friction"] or 0.0, r.get("rolling", 0.0)
    ground = (f'<geom name="floor" type="plane" size="250 250 0.1" contype="0" conaffinity="1" '
              f'condim="{6 if rolling else 3}" '
              f'friction="{friction * PLANE_FRICTION!r} {rolling * PLANE_FRICTION!r} '
              f'{rolling * PLANE_FRICTION!r}"/>')
    walls = ""
    if task.world == "octagon":
        # the original's 8 boxes (0.2 x 10 x 2 m, centred 12 m out every 45 degrees) overlap at
        # the corners (the octagon's side is 9.86 m), so inside them they act as the 8 planes of
        # their inner faces, 11.9 m out; planes are MJX's cheap contacts (boxes cost a convex
        # test per robot geom and wall: BallCircle's MJX protocol ran at 163 env steps/s on a
        # CPU with boxes, benchmarks/RESULTS.md). Above the walls' 2 m top
        # the planes still stop a robot the boxes would not (none of the robots climbs so high)
        for k, yaw in enumerate(np.linspace(0, 7 / 8 * 2 * np.pi, num=8)):
            c, s = np.cos(yaw), np.sin(yaw)
            walls += (f'<geom name="wall_{k}" type="plane" size="5 1 0.1" '
                      f'pos="{_v((11.9 * c, 11.9 * s, 1))}" zaxis="{_v((-c, -s, 0))}" '
                      f'contype="0" conaffinity="2" friction="{friction * WALL_FRICTION!r} 0 0"/>')
    custom = ""
    if contact_slots is not None:
        custom = (f'<custom><numeric name="max_contact_points" '
                  f'data="{int(contact_slots)}"/></custom>')
    return (f'<mujoco model="{task.name}"><compiler angle="degree" autolimits="true"/>'
            f'<option timestep="{task.time_step!r}" gravity="0 0 -9.81" '
            f'integrator="{r.get("integrator", "Euler")}"/>'
            f'<default><geom contype="3" conaffinity="0" friction="0 0 0" margin="0"/></default>'
            f'<asset>{r.get("assets", "")}</asset>'
            f'<worldbody>{ground}{walls}{r["body"]}</worldbody>'
            f'<tendon>{r.get("tendons", "")}</tendon>'
            f'<actuator>{r.get("actuators", "")}</actuator>{custom}</mujoco>')


def load_model(task, contact_slots="auto"):
    """mujoco.MjModel of `model_xml(task, contact_slots)`."""
    import mujoco

    return mujoco.MjModel.from_xml_string(model_xml(task, contact_slots))
