"""DPSI: differentiable physics-based system identification of elastoplastic objects.

The package is organised by what each module is. Its base layer needs only numpy, pandas and PyYAML
(:mod:`dpsi.files`, :mod:`dpsi.parameters`, :mod:`dpsi.motions`, :mod:`dpsi.effectors`,
:mod:`dpsi.heightmap`, :mod:`dpsi.datasets`, :mod:`dpsi.twin_plan`, :mod:`dpsi.datapoint`), so that the
workflow plans its jobs without loading the simulator (Taichi) or the geometry libraries (Open3D,
PyMeshLab).

- :mod:`dpsi.parameters` – the six physical parameters, their ranges and step sizes.
- :mod:`dpsi.motions` – the robot motions and trajectory resampling.
- :mod:`dpsi.effectors` – rigid end-effector shapes as signed-distance functions.
- :mod:`dpsi.simulation` – the differentiable MLS-MPM simulator.
- :mod:`dpsi.reconstruction` – point-cloud fusion, meshing and particle filling.
- :mod:`dpsi.losses` – Chamfer, earth mover's and height-map distances.
- :mod:`dpsi.identification` – gradient-based parameter identification.
"""

__version__ = "0.1.0"
