"""Flying a mission end to end: the typed :class:`~companion.launch.spec.FlySpec` (built by the command line from
its flags, by ``lab`` in code) and :func:`~companion.launch.fly.fly_mission`, which starts what the spec asks for
(the bundled vehicle, Zenoh, the recording), runs the pilot under the right runner and writes the run folder."""
