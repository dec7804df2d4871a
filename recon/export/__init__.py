"""Every file recon writes, one module per format, all atomic (a reader never sees half a file):
``glb`` (rigged, skinned, animated glTF with the camera and the outfit's morph targets), ``bvh``
(a skeleton's motion), ``mesh`` (.obj and other static meshes), ``media`` (images, MP4, GIF) and
``records`` (JSON). Commands decide which files a folder holds (recon.run.files, recon.video.outputs,
recon.animate, recon.page); the formats live here and import no stage after the body and the poses.
"""
