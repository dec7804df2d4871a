"""Garments (thesis ch. 3 and 5).

Runtime: ``templates`` (CLOTH3D-style outfits on the rest body), ``pbns`` (the network),
``ncs`` (Neural Cloth Simulation, ch. 6: descriptors, the recurrent model, the inertia term),
``resize`` (body shape + tightness), ``taylor`` (the example-based body-shape dimension),
``dress`` (any body shape and pose: ``Dresser``),
``collide`` (collision resolution), ``gltf`` (animated .glb), ``store`` (where weights live),
``mesh``. Shared: ``losses`` (PBNS energies), ``metrics`` (what the logs and tables report),
``self_intersection`` (where the posed body passes through itself), ``data`` (pose sets,
conditions). Training: ``*_train``, ``taylor_build`` (with ``drape``, the quasi-static drape
solver); evaluation: ``*_eval``, with ``reference`` (a newton cloth drape, optional extra).
Runtime modules import nothing from training or evaluation.
"""
