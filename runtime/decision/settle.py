"""Landing on a slot the robot sees only through noise: damp the last steps, then stay.

The frame a landing goes in is computed by :mod:`runtime.decision.landing_frame`
(:func:`seen_team`, :func:`seen_centroid`, :func:`view_centroid`, :func:`smooth_centroid`,
:func:`core_frame`, :func:`shared_slots`, :func:`centroid_targets`); this module keeps the
landing itself and the measurements behind each choice.

A brain or rule moves its robot to where its view says the slot is. When the view is
noisy, that place jitters from step to step by the noise the estimator leaves, and a
robot that follows it exactly never stops: the team passes through the formation and
does not hold it (with 5 cm noise `rule:frame-balanced` + the tracker formed 100 % and
held 0 % of 8 episodes). :class:`Settle` is what a robot does about it, after the
brain and before the safety filter, a **damped landing**: a step shorter than
``radius_m`` is cut to ``gain`` of itself, so the robot averages the jittering target
over about ``(2 - gain) / gain`` steps instead of chasing each one. Measured on
``benchmarks/conditions.py``'s circle and heart (n = 10, 8 episodes, 5 cm noise,
`rule:frame-balanced` + the tracker): held 0 % -> 100 %, steps 1.12x -> 1.20x the lower
bound. Tried and left out: parking (a robot whose step is under 1 cm stays until asked
for more than 2.5 cm: steps 1.70x, no better hold) and a long average of peers that keep
still (the damped landing's short steps read as still, and the team's consensus lagged:
formed 75 %, held 0 %).

**Landing frame.** A synchronised plan (the frame rules, the plan brains) places the
pattern in a frame that blends the centre of the smallest circle enclosing the team's
displacements with their centroid. The enclosing circle rests on two or three robots, so
its centre carries their noise whole, where the centroid averages every robot's: a landed
team chasing it does not hold. With ``centroid_steps`` (2; under noise 6 since "The
landing's six steps", and every step since "The centroid frame from the start") steps or
fewer left, a robot under noise lands in the centroid frame (travel weight 1). Measured
(n = 10, 4 episodes of each of ``benchmarks/conditions.py``'s shapes, `rule:frame-balanced`
+ the tracker): the realistic preset held 65 % -> 95 % of episodes, 10 cm noise 0 % -> 35 %,
at the same steps (1.50x -> 1.52x the lower bound); switching at 3 or 5 steps left did no
better.
Without noise and without latency a plan lands as planned, to the last bit.

**The centroid, averaged.** The centroid a robot sees carries the tracker's error on each
peer divided by about sqrt(n), some 1 cm at 10 cm of noise, n = 10, and the worst of ten
robots then stands 2-3 cm off: as much as the tolerance. Under the centroid frame's plan
every robot heads for its slot around the team's centroid, so the true centroid keeps still
while the team lands, and a robot may average the centroids it sees over the landing's
steps: ``centroid_gain`` (0.1, about 20 steps) of each new one. Measured on
``benchmarks/conditions.py``'s shapes (n = 10, 100 episodes per case, another seed than the
table's; `rule:frame-balanced` + the tracker), success at gains 0.05 / 0.1 / 0.2: 10 cm
noise 97 / 97 / 87 %, the realistic preset 94 / 96 / 92 %, 5 cm 100 % at each; the gain 1
(this step's centroid alone) held 14 of 20 circle and heart episodes at 10 cm where 0.1
held 19. The average lags a team that moves, and where a landing stalls (robots the safety
filter holds apart next to their slots) a lagging frame and the plan's own frame, in turn,
walked a whole team away: `launch --robots 8 --conditions realistic --estimator --seed 6`
took 196 steps from the circle to the cross, whose bound is 5, the team 2 m from where it
began. A centroid seen ``gate_sigmas`` (10) of its noise (``sigma_m / sqrt(n)``) from the
average moves it at once, and between the gain grows with the square of the distance
(:func:`smooth_centroid`): that cross then took 69 steps. Gates of 3 and 6 sigmas held 10 cm
noise 81 % and 91 % of 100 episodes where 10 held 95 %.

**Seen raw, averaged over the whole landing.** The tracker's estimates are averages
themselves: their errors last several steps, so averaging them again removes little, and
they lag a peer that stops. A landing now starts from the centroid of the tracker's
estimates, as before, and then averages the centroid seen in the raw views
(:func:`seen_centroid`: each peer where it was last sensed, the robot itself where it is),
whose errors are new each step, by their running mean (:meth:`Settle.centroid_weight`:
1 / (k + 3) on step k, the start worth 3 raw views, at least ``centroid_gain``, 0.03),
gated at 10 sigmas of the raw noise. With the true centroid instead of the seen one, 200
episodes at 10 cm noise held 98.5 % where the tracker's average held 95.5 %. Measured
(`rule:frame-balanced` + the tracker, n = 10, 600 episodes per case on seeds apart from the
table's): 10 cm noise 92.3 % -> 96.5 % (1.54x -> 1.52x the steps lower bound), 5 cm noise
97.2 % -> 96.8 % (1.15x -> 1.14x). The start's worth, 1 / 3 / 6 raw views (200 episodes):
10 cm 96 / 97 / 97.5 %, 5 cm 97.5 / 96.5 / 96 %. Each half alone did not help: the raw views
at the gain 0.1 of before held 10 cm noise 89 % of 300 episodes (91 % before), the running
mean of the tracker's centroid 94.5 % of 200 (95.5 % before).

**The filter reads the plan in the landing.** The failures left at 5 cm of noise were
teams that passed through the formation as they stopped: the tracker's velocity estimates
lag a peer that stops, and ORCA, which predicts each peer at its velocity, had robots dodge
peers that were no longer coming (a robot pushed 3 cm off its slot in one step, the team
formed and then not). In the landing every robot computes the same plan for the team and
follows it, so the filter now takes the peers' velocities from it
(:meth:`runtime.decision.controller.Controller._landing_filter`; the guard, which reads
distances only, is unchanged, and a brain without a plan keeps the tracker's). Measured
(`rule:frame-balanced` + the tracker, n = 10, 600 episodes per case on seeds apart from the
table's): 5 cm noise 96.8 % -> 100 %, 10 cm 96.5 % -> 98.5 %, the realistic preset 100 %
(1.38x). The plan's velocities over the whole run, not only the landing, took fewer steps at
10 cm (1.48x against 1.51x) at the same success; left out, as ORCA would then trust the plan
of a peer that does not follow it all the way.

**Damped by the way left.** Under a plan the landing damps a robot whose way left to its
slot is under ``radius_m``, not one whose step is short: a robot with little way to go on a
long plan steps slowly all along, and damping it held the whole team back until its plan
asked for longer steps. Brains without a plan are damped by the step's length as before.
Both together, with the damping gain of 0.5 (:data:`SETTLE_GAIN`) and the gate, against the
landing before them (``benchmarks/conditions.py``, n = 10, 100 episodes per case,
`rule:frame-balanced` + the tracker): 10 cm noise 73 % at 1.87x the steps lower bound -> 93 %
at 1.64x (the general brain 80 % -> 93 %, 1.65x), 5 cm noise 99 % at 1.21x -> 100 % at 1.15x,
the realistic preset 92 % -> 97 % (1.63x -> 1.44x with the tracker's late views carried along
the plan), 0 collisions, the charging adversary's included
(``benchmarks/results/conditions_landing_10.txt``). The gate's price: 10 cm noise held 89 % of
200 episodes on other seeds where no gate held 94 % (20 sigmas: 92 %, and the walk above
came back, 248 steps).

**The guard near the slot.** The safety filter's last-resort guard reads the raw views and
keeps a pair at least ``2 (R + radius margin + guard margin)`` apart as seen: at 10 cm of
noise 0.45 m, wider than the patterns' 0.40 m between neighbouring slots. A pair inside it may
not close in at all (within a cone of the seen direction), so a landed robot that strays out
by a centimetre cannot come back while its neighbour stays, and the team, slowly formed,
loses the tolerance in its hold window. Measured on 200 episodes of the table's seeds at
10 cm (`rule:frame-balanced` + the tracker): with the true centroid instead of the averaged one
95.5 % held, with it and no filter at all 99.5 %, with neither change 92.5 %; without the
guard (ORCA alone on the estimates) 83 %. A robot that lands in the centroid frame within
``landed_m`` (5 cm) of its slot is *landed* and its guard keeps ``guard_share`` (0.5) of its
margin (0.35 m at 10 cm): it may close in on its slot, by the landing's damped steps; the
full guard stays for every robot on its way and for every brain without a plan (the charging
adversary). Measured (n = 10, 300 episodes per case on seeds apart from the table's): 10 cm
noise 89 % at 1.64x the lower bound -> 91 % at 1.54x, the realistic preset 97 % at 1.45x ->
99 % at 1.40x, 5 cm 98 % -> 98 % at 1.15x, 2 steps late unchanged (1.16x), 0 collisions;
shares 0.3 and 0.7 came within a point of 0.5, and 10 cm of way instead of 5 took fewer steps
(1.47x, 1.36x) but held less of the realistic preset (97 %). Since the landing reads the plan
in its filter and the raw centroid, and the guard's margin bounds the wheels' gain on the
command, every robot in the landing is landed (``landed_m`` infinite, as for late exact
views; a landing starts at 2 steps left, when every robot is within 0.2 m of its slot, and
10 or 20 cm of way already were the whole landing). Measured (`rule:frame-balanced` + the
tracker, n = 10): on the table's seeds (100 episodes) the realistic preset 100 % at 1.30x ->
100 % at 1.25x the lower bound, 10 cm 97 % at 1.51x -> 97 % at 1.38x, 5 cm 100 % at 1.14x ->
1.13x, 0 collisions (10 cm of way: 1.28x, 96 % at 1.42x); on 600 other episodes per case
(seed 7000000) the realistic preset 99.7 % at 1.31x -> 99.5 % at 1.26x, 10 cm
98.5 % at 1.51x -> 97.0 % at 1.39x, 5 cm 100 % at 1.13x, 0 collisions.

**Late views land in the centroid frame.** With exact views that come late (no noise),
a team that arrives together passed through its formation: each robot plans from peers
carried along its plan over their views' age, and a peer the safety filter had held back
shows up where the plan did not put it a few steps later, moving the plan's frame and the
landed team with it. The filter's guard used to hide this by slowing every landing; since
the guard lets the robot that arrives take the room a landed peer does not need
(:func:`runtime.decision.safety.guard_shares`), teams arrive at speed, and a team 3 steps
late held 88 % of 100 episodes. Landing in the centroid frame, which a team landing in it
does not move, brings them back: under latency without noise a robot lands in it too, as
it sees it raw (its peers where last sensed; exact views need no average: the gate is 0),
undamped (the damping changed nothing there). Without the safety filter this costs up to
one step less than the views' age (tests/unit/runtime/decision/test_conditions.py); with it,
measured with the shares on ``benchmarks/conditions.py``'s shapes (n = 10, 20 episodes
each, `rule:frame-balanced` + the tracker): 3 steps late 1.28x the steps lower bound, all
held -> 1.15x and 88 % held with the shares alone -> 1.13x, all held, with the landing. The
centroid of the team as the tracker carries it along the plan took fewer steps (1.12x) but
walked stalled teams away: where the guard holds two robots apart next to their slots, the
carried centroid counts them where the plan would have put them, the frame moves toward
it, and the team follows (`launch --robots 8 --conditions latency_steps=3 --estimator`,
seeds 4-8: 6 of 20 patterns not formed, 3 with the raw centroid, 3 before either change).
What still stalled there is a robot bound for the cross's centre slot, between four
neighbours 0.57 m apart: passing between two of them it comes within 0.28 m of each, and the
full guard keeps 0.29 m at 2 steps late, 0.32 m at 3. With exact views the guard's margin is
only the latency's slack, so every robot landing in the centroid frame keeps the landed
robot's half of it (``landed_m`` infinite: 0.27 m at 2 steps late, 0.28 m at 3); brains
without a plan (the charging adversary) keep the full guard. The same launches: 1 of 20
patterns not formed at 3 steps late (1,418 steps in all, where it was 3 in 2,126), 2 at 2
steps (2,002 steps; 1 in 2,260), 0 collisions; in ``benchmarks/conditions.py`` (20 episodes
per shape, the table's seeds) 1-3 steps late 1.07x / 1.08x / 1.11x, all held, the adversary
0 collisions.

**The centroid of one moment.** The raw centroid counted each peer where it was last seen
and the robot itself where it is now: on late views two moments, and a centroid of its own
for every robot. :func:`seen_centroid` now counts the robot where it stood when it saw its
peers (its pose of their views' age, from the guard's references), so on exact late views
every robot sees the team's centroid of that moment, the same for all, which a team landing
in it does not move. Measured (``benchmarks/conditions.py``, n = 10, 100 episodes, with the
guard's retreat of :meth:`runtime.core.orca.OrcaFilter.robot`): 2 / 3 steps late 1.078x /
1.101x -> 1.075x / 1.086x the steps lower bound, n = 25 3 steps late 1.127x (1.161x before
both), the realistic preset 1.231x -> 1.233x, all held, 0 collisions. The guard keeps no
margin of its own for exact late views now, so ``landed_m`` changes nothing there.

The centroid frame has a price: the plan's frame moves with the team, and its centroid frame
starts where the team is, a step or two short of where the plan would have put it, so the
team lands a step later. One step late, a team lands as planned (:data:`LANDS_AS_PLANNED_LATE`):
it held every episode without the centroid frame, and took 1.071x -> 1.050x the steps lower
bound at n = 10 (600 other episodes: 1.072x -> 1.051x, the perfect world's 1.048x), 1.102x ->
1.077x at n = 25 and 1.163x -> 1.133x at n = 50. Two and three steps late it still needs the
frame: without it, n = 25, 40 episodes, 97.5 % and 90 % held.

**The plan's frame, kept, then the team's core's.** The centroid frame costs its step
because it starts where the team is, short of where the plan puts it; the plan's own frame,
followed to the end, walks with every robot the guard holds back. A landing on exact late
views now keeps the plan's frame as it stands on the landing's first step, for
``plan_frame_steps`` steps (the landing's 2, the views' age to see it, and one more). The
robot asks the plan for that frame from the team of one moment, :func:`seen_team` (each peer
where last seen, itself where it stood then), not from its peers carried along the plan to
now: on exact views every robot then asks from the same team and gets the same frame.
Measured (``benchmarks/conditions.py``, `rule:frame-balanced` + the tracker, 100 episodes per
shape at n = 10 and 40 at n = 25): 2 / 3 steps late 1.076x / 1.087x -> 1.058x / 1.072x the
steps lower bound at n = 10, 1.111x / 1.129x -> 1.089x / 1.112x at n = 25, all held, 0
collisions. Without the safety filter every episode of the tests' lands in the perfect
world's steps (the centroid frame: up to a step less than the views' age more). Tried: the
frame kept for good left 2 of 500 episodes at n = 10 and 1 of 200 at n = 25 unformed (three
steps late; robots that start their landings a step apart ask from two moments); the frame
from the peers carried to now, kept for the same steps, 1.079x / 1.121x at three steps late;
starting the landing a step earlier or keeping the frame 4 steps changed nothing.

A team still landing after that lands in the frame of its core (:func:`core_frame`: each
robot's position less its slot point, the team seen of one moment, averaged over the robots
within ``CORE_M`` (0.2 m) of the median robot's) at the slots that moment gives every robot
alike (:func:`shared_slots`, solved cold), not the centroid frame at the robot's own slots.

- *The core.* Where the guard holds a robot off its slot (the cross's centre, between four
  neighbours), the centroid frame moves by the robot's share of the way it is off, every
  step, and the team walks after it: `launch --robots 8 --conditions latency_steps=3
  --estimator`, seed 15, walked 4 m and left the cross unformed in 400 steps. The core leaves
  that robot out; with every robot in it, as in a team that has formed, it is the centroid
  frame, which a team landing in it does not move. The median robot's frame alone, tried
  first, did not walk either, but it moves while the team settles: the team seen 3 steps late
  is still moving, and 2 of the 52 patterns of `launch --robots 10 --hold-steps 20` (3 steps
  late, seeds 0-12) did not hold, where the core held all.
- *One moment's slots.* The robot's own assignment keeps its hysteresis along its own views,
  which carry its peers along its own plan: with `--robots 10 --conditions latency_steps=2
  --seed 8` one robot, assigned a landed neighbour's slot, saw that neighbour carried toward
  the slot it had given it, while every other robot gave it the free one, and it pushed at
  the neighbour for 400 steps. On exact views the team of one moment is the same for every
  robot, and so is its assignment.

Measured on `launch --estimator` (circle, cross, line, heart; 10 robots seeds 0-12 and 8
robots seeds 4-16, 104 patterns; total steps and patterns not formed, 0 collisions): 2 steps
late 6,089 and 4 before the plan's frame -> 3,588 and 1 now; 3 steps late 6,524 and 5 ->
4,461 and 0. With `--hold-steps 20` (10 robots): 2 steps late 3,033 steps, 2 not formed and 2
not held -> 1,753, all held; 3 steps late 2,731, all held -> 2,247, all held.
``benchmarks/conditions.py`` (random starts, where few landings last past the kept frame) is
unchanged by the core and the shared slots at n = 10 and n = 25; at n = 50 (100 episodes) 3
steps late took 1.177x the lower bound with the centroid frame after the plan's, 1.163x now.

**Parked inside the tolerance, on noisy wheels that turn.** A differential-drive base whose
wheels add noise whenever it moves gains nothing from correcting a few millimetres: to
move sideways it turns first, creeping along its heading meanwhile, and every step it moves
the wheels add their 2 cm/s of noise, more than the correction. Under the ``harsh`` preset
the team formed and then drifted apart (held 44 % of the formed at a 0.55 m spacing). There
a robot whose way to its slot in the landing is under ``park_m`` (0.6 of the formed
tolerance, 1.5 cm) stays where it is, exactly still, until the way grows past ``unpark_m``
(0.8 of it, 2.0 cm; it was the tolerance, 2.5 cm, below). Measured (`rule:frame-balanced`
+ the tracker, n = 10, 100 episodes on ``benchmarks/conditions.py``'s shapes and seeds):
``harsh`` with the shapes spaced 0.55 m 44 % -> 78 %, at the built-ins' 0.40 m 13 % -> 22 %
(in 40 of those episodes, 1.0 / 2.0 cm
held 41 % of the formed where 1.5 / 2.5 held 88 %, 2.0 / 3.0 71 %). Elsewhere it did not
help and is off: with noise on holonomic wheels (the realistic preset) or on a differential
drive without wheel noise it took more steps for the same success or less (40 episodes:
realistic 1.24x -> 1.28x, 10 cm noise 95 % -> 85 %).

Moving again past 2.0 cm, not 2.5: in the team's one frame (the leader's) a robot knows its
way to its slot, but the formation is judged about the team's own mean, which the parked
robots' offsets move; a robot parked 2-2.5 cm off, its team's mean a centimetre the other
way, stood 3-3.5 cm off for the rest of the hold. `rule:frame-balanced` + the tracker under
``harsh`` (``benchmarks/conditions.py``, 0 collisions): n = 10 on five seed sets 69.4 % ->
74.6 % held, n = 25 77 % -> 86 % (docs/conditions.md, "Under `harsh`: a parked robot moves
again sooner").

**The landing's six steps.** Under noise a plan lands in the centroid frame for its last
:data:`NOISY_LANDING_STEPS` (6) steps, where it was 2. The last steps of a plan bring every
robot next to its neighbours' slots, 0.40 m apart, and the full guard keeps 0.35 m between
centres as seen at 5 cm of noise, 0.45 m at 10 cm: it bound nearly every arrival there, one
robot at a time, and the farthest robot sets a synchronised team's pace. In the landing
every robot is landed and keeps half the guard's margin, reads its peers' velocities from
the plan and averages the centroid over more views. Measured on ``benchmarks/conditions.py``
(`rule:frame-balanced` + the tracker, 100 episodes per case, the table's seeds; 0 collisions,
the charging adversary's included, which has no plan and keeps the full guard):

- n = 10: the realistic preset 99 % at 1.235x the steps lower bound -> 100 % at 1.209x, 10 cm
  noise 97 % at 1.384x -> 100 % at 1.277x, 5 cm 1.134x -> 1.130x; ``harsh`` 52 % (88 %
  formed) at 5.1x -> 59 % (100 % formed) at 2.8x, with the lost updates' reference.
- n = 25: the realistic preset 1.364x -> 1.313x, 10 cm 1.593x -> 1.401x.
- n = 50 (40 episodes): the realistic preset 95 % at 1.475x -> 97.5 % at 1.410x, 10 cm
  1.818x -> 1.517x.
- 4 / 6 / 8 / 12 / 20 steps at n = 25 under the realistic preset: 1.349x / 1.331x / 1.326x /
  1.366x / 1.409x (before the lost updates' reference of
  :meth:`runtime.decision.local.Perception.perceive`; 2 steps: 1.380x). Past 8 steps the
  centroid frame, which is not the one that brings the farthest robot in soonest, costs more
  than the guard gives back.
- Half the guard's margin in the last 8 steps without the centroid frame took 1.325x there:
  the guard is most of it.

On `launch --estimator --hold-steps 20` (the pymunk world, one process per robot, lockstep):
8 robots under the realistic preset, seeds 1-5, 688 steps -> 636, and 10 robots at 10 cm
noise, seeds 0-5, 1,217 steps with 1 pattern not held -> 981, all held; 0 collisions.

**Each at its own pace.** Under noise every robot of a landing goes its own way to its slot
over its own steps left (``Settle.own_pace``, :func:`landing_steps`: its way at v_max), where
it took the team's, the farthest robot's. The team's steps left come from the peers' noisy
positions: the largest of n noisy ways, rounded up to whole steps, overstates them, and every
robot of the landing went slower for it (at n = 25 under 5 cm of noise, the steps left from
the true positions took 1.191x -> 1.166x). Its own way a robot knows from its own pose. Every
robot works out each peer's velocity by the same rule
(:func:`runtime.decision.rules.pace_velocity`), for its filter
and for the peers it carries along the plan; the filter's horizon and the landing's switch
still read the team's steps left. The team's centroid now moves while robots that arrive
first wait, and the averaged frame follows it late: at 10 cm of noise a few more teams do not
hold. Measured (``benchmarks/conditions.py``, `rule:frame-balanced` + the tracker, 100
episodes per case; 0 collisions):

- n = 10: 5 cm 1.130x -> 1.099x, 10 cm 100 % at 1.277x -> 97 % at 1.193x (600 other
  episodes: 99.3 % at 1.282x -> 96.5 % at 1.197x), the realistic preset 1.209x -> 1.193x,
  ``harsh`` 59 % at 2.84x -> 66 % at 2.85x.
- n = 25: 5 cm 1.191x -> 1.138x, 10 cm 1.401x -> 1.274x, the realistic preset 1.317x ->
  1.285x (200 other episodes: 1.349x -> 1.300x).
- n = 50: 10 cm 100 % at 1.533x -> 97 % at 1.392x, the realistic preset 99 % at 1.441x ->
  1.384x.
- Tried: velocities less their mean, so that the team's centroid keeps still, held 49 % at
  10 cm (a landed robot moved with the others' mean); the team's steps less one as a floor
  for each robot's took 1.295x / 1.147x at n = 25 (the realistic preset / 5 cm) and held 97 %
  at 1.209x of 300 of the other episodes at 10 cm.

**The centroid frame from the start.** Under noise a synchronised plan goes in the team's
centroid frame, averaged, from its first step (``Settle.centroid_steps`` infinite), where it
took it for its last six, each robot at its own pace. The plan's own frame blends in the
centre of the smallest circle enclosing the team's displacements, which rests on two or
three robots and carries their noise whole: the robots' frames disagreed all the way in, and
the more robots, the more. The centroid of a team heading for its slots around it keeps
still, so its average over the whole run is the steadiest frame each robot can have. The
filter reads the peers' velocities from the plan, and landed robots keep half the guard,
for the last six steps only (``Settle.filter_steps``): before, ORCA keeps the tracker's, as
it would otherwise trust a plan a peer may not follow all the way. Measured
(``benchmarks/conditions.py``, `rule:frame-balanced` + the tracker, the table's seeds, 100
episodes per case at n = 10 and 25, 50 at n = 50; 0 collisions, the charging adversary's
included; ``benchmarks/results/conditions_centroid_frame.txt``):

- n = 10: 10 cm 97 % at 1.193x -> 99 % at 1.162x, the realistic preset 1.193x -> 1.192x,
  5 cm 1.099x -> 1.104x, ``harsh`` 65 % -> 68 % (2.86x -> 2.84x).
- n = 25: 10 cm 1.274x -> 1.201x (100 % -> 99 %), the realistic preset 1.286x -> 1.235x,
  5 cm 1.138x -> 1.141x.
- n = 50: 10 cm 98 % at 1.386x -> 100 % at 1.271x, the realistic preset 98 % at 1.380x ->
  100 % at 1.307x, 5 cm 1.182x -> 1.194x.
- On another seed (5000000, 100 episodes): the realistic preset at n = 50 1.404x -> 1.337x.
  Tried: the filter on the plan for the whole run too, 10 cm at n = 25 1.224x -> 1.197x, the
  realistic preset at n = 50 1.337x -> 1.340x; left out, for the reason above.
- Tried: the team's pace until the last six steps, so that the team's centroid keeps still
  all the way: n = 10 at 10 cm 1.263x, the realistic preset at n = 50 1.457x; own pace it is.
- `launch --conditions realistic` (10 robots, circle, cross, line, heart; seeds 1-6): 790 ->
  762 steps in all; with `--estimator --hold-steps 20`, seeds 1-12: 2,757 -> 2,800, all held,
  0 collisions, one cross of seed 1 stalling 65 steps (21 before), seeds 7-12 1,360 -> 1,357.

:func:`settle_for` sizes it from the noise the robot knows (none in the perfect world,
which lands as before, to the last bit).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from runtime.conditions import Conditions
from runtime.core.plan_frame import steps_left
from runtime.decision.estimator import steady_sigma
from runtime.decision.landing_frame import CORE_M, core_frame, smooth_centroid, view_centroid
from runtime.decision.safety import OrcaParams
from runtime.types import Array, BoolArray
from runtime.world_config import DEFAULT_WORLD, WorldConfig

__all__ = ["CENTROID_FRAME", "Lander", "Settle", "damp_landing", "landing_gain", "landing_steps",
           "settle_for"]


@dataclass(frozen=True)
class Settle:
    """The landing's tuning (see the module docstring). Units in the names."""

    radius_m: float
    gain: float = 0.5
    centroid_steps: float = 2.0
    """A synchronised plan with this many steps left or fewer lands in the team's centroid
    frame (see the module docstring, "Landing frame"; under noise from the start, "The
    centroid frame from the start")."""
    filter_steps: float = 2.0
    """With this many steps left or fewer (and in the centroid frame) the safety filter
    reads the peers' velocities from the team's plan, and a landed robot keeps
    ``guard_share`` of the guard's margin (see "The filter reads the plan in the landing")."""
    centroid_gain: float = 0.03
    """The landing frame's centroid is the team's, as the robot sees it raw
    (:func:`seen_centroid`), averaged over the landing's steps: their running mean, each new
    one weighing at least this (see "The centroid, averaged")."""

    centroid_prior: float = 3.0
    """The landing's average starts from the centroid of the tracker's estimates, worth this
    many raw ones (see "Seen raw, averaged over the whole landing")."""

    sigma_m: float = 0.0
    """The raw view's position error on one peer (m, per axis): the centroid seen raw of n
    robots carries about ``sigma_m / sqrt(n)`` of it."""
    gate_sigmas: float = 10.0
    """A seen centroid this many of its sigmas off the average moves the average at once
    (see "The centroid, averaged")."""

    park_m: float = 0.0
    """A robot whose way to its slot in the landing is under this (m) stays still until it
    grows past ``unpark_m`` (0: never; see "Parked inside the tolerance")."""
    unpark_m: float = 0.0
    """The way to its slot (m) past which a parked robot moves again."""

    landed_m: float = math.inf
    """A robot landing in the centroid frame this close to its slot (m) is *landed*: its
    guard keeps ``guard_share`` of its margin (see "The guard near the slot"; infinite: every
    robot in the landing, under noise as with late exact views)."""
    guard_share: float = 0.5
    """The share of the safety filter's guard margin a landed robot keeps."""

    own_pace: bool = False
    """In the landing every robot goes its own way to its slot at its own pace, its own steps
    left, not the team's (under noise; see "Each at its own pace")."""

    plan_frame_steps: int = 0
    """For this many steps a landing keeps the frame the plan gives the team of one moment
    as the robot sees it at the landing's first step, then lands in the frame of the team's core
    (0: the centroid frame from the start; see "The plan's frame, kept, then the team's
    core's")."""

    def landed_safety(self, params: OrcaParams) -> OrcaParams:
        """``params`` as a landed robot's filter has them: ``guard_share`` of the guard
        margin (see "The guard near the slot")."""
        return replace(params, guard_margin_m=self.guard_share * params.guard_margin_m)

    def lands_in_centroid(self, steps_left: Any) -> Any:
        """Whether a plan with ``steps_left`` (a number or an array) lands in the centroid
        frame (travel weight :data:`CENTROID_FRAME`) rather than its own."""
        return np.asarray(steps_left) <= self.centroid_steps

    def filters_on_plan(self, steps_left: float) -> bool:
        """Whether a plan with ``steps_left`` in the centroid frame has the safety filter
        read the team's plan, and a landed robot's guard (``filter_steps``)."""
        return bool(steps_left <= self.filter_steps) and bool(self.lands_in_centroid(steps_left))

    def centroid_weight(self, k: Any) -> Any:
        """The weight of the centroid seen raw on the landing's step ``k`` >= 1 in the average
        (step 0 starts it from the tracker's): ``max(centroid_gain, 1 / (k + centroid_prior))``,
        the running mean, then an average that keeps following."""
        return np.maximum(self.centroid_gain,
                          1.0 / (np.asarray(k, dtype=np.float64) + self.centroid_prior))

    def centroid_gate(self, n: Any) -> Any:
        """How far (m) the centroid seen by a robot of ``n`` may stray from its average
        before it moves the average at once (``gate_sigmas`` of its noise)."""
        return self.gate_sigmas * self.sigma_m / np.sqrt(np.maximum(n, 1))


CENTROID_FRAME = 1.0
"""The travel weight of the team's centroid frame, where a plan lands under noise."""


def settle_for(conditions: Conditions, estimator: bool = False,
               world: WorldConfig = DEFAULT_WORLD) -> Settle | None:
    """The landing for a robot sensing under ``conditions`` (None: land as planned): under
    noise damped, in the centroid frame averaged; with exact views 2 or more steps late, in
    the plan's frame kept, then the frame of the team's core as seen, undamped (see "Late
    views land in the centroid frame" and "The plan's frame, kept, then the team's core's"; one
    step late lands as planned, see "The centroid of one moment")."""
    if conditions.noise_m <= 0.0:
        late = conditions.latency_steps
        if late <= LANDS_AS_PLANNED_LATE:
            return None
        keep = math.ceil(Settle.centroid_steps) + late + 1  # landed, seen, and a step to spare
        return Settle(radius_m=0.0, gain=SETTLE_GAIN, sigma_m=0.0, plan_frame_steps=keep)
    sigma = steady_sigma(conditions.noise_m) if estimator else conditions.noise_m
    parks = conditions.kinematics == "diff" and conditions.act_noise_mps > 0.0
    return Settle(radius_m=min(SETTLE_SIGMAS * sigma, 0.5 * world.max_step_m),
                  gain=SETTLE_GAIN, centroid_steps=math.inf, filter_steps=NOISY_LANDING_STEPS,
                  sigma_m=conditions.noise_m, own_pace=True,
                  park_m=PARK_SHARE * world.formed_tol_m if parks else 0.0,
                  unpark_m=UNPARK_SHARE * world.formed_tol_m if parks else 0.0)



NOISY_LANDING_STEPS = 6.0
"""Under noise a synchronised plan with this many steps left or fewer has its safety filter
read the team's plan, every robot of it landed (``Settle.filter_steps``; see "The landing's
six steps"); it goes in the centroid frame, averaged, from the start (see "The centroid
frame from the start")."""

LANDS_AS_PLANNED_LATE = 1
"""Exact views at most this many steps late land as planned, not in the centroid frame (see
"The centroid of one moment")."""

PARK_SHARE = 0.6
"""Where a robot parks (``Settle.park_m``), as a share of the formed tolerance."""
UNPARK_SHARE = 0.8
"""Where a parked robot moves again (``Settle.unpark_m``), as a share of the formed
tolerance: below it, so that the team's mean offset in its shared frame has room under the
tolerance (see "Parked inside the tolerance")."""


SETTLE_SIGMAS = 2.5
"""Steps shorter than this many sigmas of the estimate's noise are damped."""
SETTLE_GAIN = 0.5
"""The damping of the last steps. 0.3 until the landing's centroid was averaged; since,
`rule:frame-balanced` + the tracker (n = 10, ``benchmarks/conditions.py``'s shapes, 200
episodes per case on seeds apart from the table's) formed and held as often at 0.5 in fewer
steps: 5 cm noise 99 % at 1.20x -> 99 % at 1.16x the lower bound, 10 cm 95 % at 1.75x -> 94 %
at 1.65x; 0.7 and 1 (no damping) lost success at 10 cm (89 %, 82 % of 100 episodes)."""


class Lander:
    """One robot's landing: the damping, and the landing frame's centroid averaged over the
    steps of one landing (the controller resets it with its history)."""

    def __init__(self, settle: Settle, dt_s: float) -> None:
        self.settle = settle
        self.dt_s = dt_s
        self.reset()

    def reset(self) -> None:
        """Forget the centroid (the next landing starts from its first view)."""
        self._tick = -2
        self._k = 0  # the landing's steps so far
        self._base: Array | None = None  # the centroid as of the landing's last step
        self._m: Array | None = None  # and as of this one
        self._frame: Array | None = None  # the plan's frame kept from the landing's start
        self._parked = False

    def centroid(self, seen: Array, tick: int, n: int, start: Array | None = None) -> Array:
        """The landing frame's centroid (2,) m, from the team's as seen this step, ``seen``
        (a team of ``n``), on the controller's step ``tick``: the same tick again (realtime)
        redoes this step's
        average, a tick that does not follow the last one starts a new landing."""
        if tick == self._tick and self._base is not None:
            prev: Array | None = self._base
        elif tick == self._tick + 1 and self._m is not None:
            prev = self._m
            self._k += 1
        else:
            prev = None
            self._k = 0
        self._base, self._tick = prev, tick
        if prev is None and start is not None:  # a landing starts from the tracker's
            self._m = np.array(start, dtype=np.float64)
        else:
            self._m = smooth_centroid(prev, seen, float(self.settle.centroid_weight(self._k)),
                                      float(self.settle.centroid_gate(n)))
        return self._m

    def frame(self, team: Array, points: Array, tick: int, start: Array,
              planned: Callable[[Array], Array],
              shared: Callable[[Array], Array] | None = None,
              in_view: BoolArray | None = None) -> tuple[Array, Array]:
        """The landing frame's centroid (2,) m and the slot points (n, 2) it holds, from the
        team (n, 2) as the robot sees it raw (:func:`seen_team`) and its slot points
        ``points``: :meth:`centroid`'s of the team's centroid (``tick``, ``start`` as there);
        on exact late views (``plan_frame_steps`` > 0) for the landing's first
        ``plan_frame_steps`` steps the centroid of the team's targets that ``planned(team)``
        gives on its first step, kept, then the :func:`core_frame` of the slot points
        ``shared(team)`` gives, an assignment every robot makes alike from the team of one
        moment (None: ``points``; see "The plan's frame, kept, then the team's core's").
        ``in_view`` (n,): the peers the robot has in view, where it sees part of its team;
        the centroid is then the one they show (:func:`view_centroid`)."""
        m = self.centroid(view_centroid(team, points, in_view), tick, len(team), start)
        keep = self.settle.plan_frame_steps
        if keep <= 0:
            return m, points
        if self._k >= keep:
            if shared is not None:
                points = shared(team)
            return core_frame(team, points, CORE_M), points
        if self._k == 0 or self._frame is None:
            self._frame = np.asarray(planned(team), dtype=np.float64)
        return self._frame, points

    def apply(self, vx: float, vy: float, to_slot_m: float | None = None
              ) -> tuple[float, float]:
        """The brain's velocity (m/s) as the landing lets it through; ``to_slot_m`` the
        robot's way left to its slot under a plan (None: the step's length)."""
        far = math.hypot(vx, vy) * self.dt_s if to_slot_m is None else to_slot_m
        st = self.settle
        if to_slot_m is not None and st.park_m > 0.0:
            self._parked = far < (st.unpark_m if self._parked else st.park_m)
            if self._parked:
                return 0.0, 0.0
        g = st.gain if far < st.radius_m else 1.0
        return vx * g, vy * g


def landing_steps(target: Array, pos: Array, team_steps: Any, settle: Settle,
                  world: WorldConfig = DEFAULT_WORLD) -> Array:
    """Each robot's steps left in a landing (..., n): with ``settle.own_pace`` its own, those
    of its way to its ``target`` at v_max (at least 1), else its team's ``team_steps``
    (...,), as :func:`centroid_targets` gives them."""
    d = np.asarray(target, dtype=np.float64) - np.asarray(pos, dtype=np.float64)
    if settle.own_pace:
        own: Array = steps_left(np.sqrt(d[..., 0] ** 2 + d[..., 1] ** 2),
                                world.v_max_mps * world.dt_s)
        return own
    return np.broadcast_to(np.asarray(team_steps, dtype=np.float64)[..., None], d.shape[:-1])


def landing_gain(far_m: Any, settle: Settle) -> Any:
    """The landing's factor for a robot ``far_m`` from its slot, or whose step is that long
    (a number or an array): ``gain`` under ``radius_m``, else 1."""
    return np.where(np.asarray(far_m) < settle.radius_m, settle.gain, 1.0)


def damp_landing(velocity: Array, settle: Settle, dt_s: float,
                 to_slot_m: Array | None = None) -> Array:
    """Velocities (..., 2) m/s as the landing lets them through (the training world's robots,
    as :class:`Lander` a robot's); ``to_slot_m`` (...) each robot's way left to its slot
    under a plan (None: each step's length)."""
    v = np.asarray(velocity, dtype=np.float64)
    far = np.hypot(v[..., 0], v[..., 1]) * dt_s if to_slot_m is None else to_slot_m
    out: Array = v * landing_gain(far, settle)[..., None]
    return out
