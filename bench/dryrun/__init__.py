"""The dry run: the controller in the loop with the drives, cycle after cycle.

- :mod:`bench.dryrun.loop`: the control loop on the hardware interface only
  (``read()`` -> trajectory setpoint -> ``LengthController.step`` -> supervisor ->
  ``write_lengths()``), the same code for :class:`hal.fake.FakeHardware`, the simulated
  rig in this process, ``cdpr sim`` in another process and real drives;
- :mod:`bench.dryrun.hardware`: the buses it is given (``--site``, ``--can``, ...), opened
  as they are, nothing started; never imports ``firmware_sim``;
- :mod:`bench.dryrun.preflight`: the read-only checks before anything moves on them;
- :mod:`bench.dryrun.world`: the simulated robot the loop runs against (drives, load
  cells, tracker and plant; in this process, or ``cdpr sim`` as a process reached through
  the site it writes, i.e. the hardware world);
- :mod:`bench.dryrun.realtime`: what a real-time loop asks of its process (interpreter
  settings, SCHED_FIFO for its thread when permitted);
- :mod:`bench.dryrun.record`: the recording written while the run goes;
- :mod:`bench.dryrun.scenarios`: shipped dry-run scenarios by name;
- :mod:`bench.dryrun.report`: summary, text table and plots.
"""
