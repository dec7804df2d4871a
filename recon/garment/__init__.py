"""Garments (thesis ch. 3-6).

Runtime: ``templates`` (CLOTH3D-style outfits on the rest body), ``pbns`` (the network),
``ncs`` (Neural Cloth Simulation, ch. 6: descriptors, the recurrent model, the inertia term),
``resize`` (body shape + tightness), ``taylor`` (the example-based body-shape dimension),
``deepsd`` (any outfit mesh to W and D without training, ch. 4), ``gcvae`` and ``gcvae_sample``
(the generative garment space, 3.4), ``dress`` (any body shape and pose: ``Dresser``),
``collide`` (collision resolution), ``gltf`` (animated .glb), ``store`` (where weights live),
``mesh``. Shared: ``losses`` (PBNS energies), ``metrics`` (what the logs and tables report),
``self_intersection`` (where the posed body passes through itself), ``data`` (pose sets,
conditions), ``outfits`` (a distribution of generated outfits with held-out styles).
Training: ``*_train``, ``*_data``, ``taylor_build`` (with ``drape``, the quasi-static drape
solver); evaluation: ``*_eval``, with ``reference`` (a newton cloth drape, optional extra).
Runtime modules import nothing from training or evaluation.
"""
