"""The hexapod's spiking CPG of the hexapod SCPG paper: gait patterns, the network and its training.

- `robots.hexapod.gaits`: leg numbering and the three gait patterns of Fig. 2
  (`PATTERNS`, `required_spikes`), written down once.
- `robots.hexapod.cpg`: the SCPG of Fig. 2(a), discrete LIF neurons of
  Eq. (1)-(2) (`CPGWeights`, `cpg_weights_init`, `cpg_init`, `cpg_step`,
  `run_gait`).
- `robots.hexapod.training`: Alg. 1, the stochastic supervised rule programming
  the gaits (`train`, `gait_correct`).
- `robots.hexapod.reference`: Alg. 1 as plain NumPy loops, the tests' oracle and
  the benchmark's peer.
- `robots.hexapod.trial`: the gait-convergence trial that sweep files name
  (`convergence_trial`, `replay_trial`).
- `robots.hexapod.reproduce`: ``spikejax reproduce gaits`` and ``gait-choices``.
- `robots.hexapod.bench`: ``spikejax bench gaits``.
"""
