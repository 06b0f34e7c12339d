"""Real-to-sim object reconstruction (SPEC §3): :mod:`.fusion` of camera views into a closed cloud,
:mod:`.meshing` into a watertight mesh, :mod:`.filling` with particles and the loss targets."""
