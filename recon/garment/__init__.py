"""Garments (thesis ch. 3-6): a core and one district per model family.

Core, inference: ``templates`` (CLOTH3D-style outfits on the rest body), ``outfits`` (a
distribution of generated outfits with held-out styles), ``mesh``, ``resize`` (body shape +
tightness), ``dress`` (any body shape and pose: ``Dresser``), ``collide`` (collision resolution),
``morph`` (an outfit as skinning + morph targets for a .glb), ``store`` (where weights live),
``losses`` (the cloth energies), ``metrics``, ``self_intersection``. Core, training: ``data`` (pose sets, posed bodies),
``integrate`` (the implicit cloth integrator), ``drape`` (the quasi-static drape), ``reference``
(a newton cloth drape, an optional extra).

Families, each a subpackage with the same rooms (``model`` for inference, ``data``, ``train``,
``eval``; a few have ``config``, ``losses``, ``sample`` or ``command``): ``pbns`` (ch. 5),
``ncs`` (Neural Cloth Simulation, ch. 6), ``deepsd`` (any outfit mesh, ch. 4), ``gcvae`` (the
generative garment space, 3.4), ``taylor`` (example-based body-shape synthesis), ``author``
(keyframe authoring). Inference imports nothing from training or evaluation (tests/test_layout.py).
"""
