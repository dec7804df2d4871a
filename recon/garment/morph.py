"""A Dresser's outfit as glTF animates it (``recon.export.glb.BlendAnimation``): the outfit's rest
mesh skinned by its joints, its deformations as morph targets and their weights per frame. PBNS
is skinning + PSD, which glTF runs natively: its rows of D are the targets, its embedding
X(theta) their weights; a motion takes NCS's codes where the outfit has an NCS, Taylor's blend
where it is a Taylor outfit; a photo's post-step is one more target at weight 1."""
from __future__ import annotations

import numpy as np
import torch

from recon.body.base import BodyModel
from recon.body.lbs import blend_transforms
from recon.export.glb import INFLUENCES, BlendAnimation, written_weights


def post_step_target(body: BodyModel, shape: torch.Tensor, rotmats: torch.Tensor, transl: torch.Tensor, dresser,
                     rest: np.ndarray, targets: np.ndarray, weights: np.ndarray,
                     influences: int | None = INFLUENCES) -> np.ndarray:
    """The Dresser's post-step (recon.garment.collide) on one posed frame as a rest-pose morph
    target (N, 3): its result taken back through each vertex's blended skinning matrix as the
    file skins (``influences``), so that skinning the outfit with it at weight 1 gives what the
    Dresser returns."""
    model = dresser.model
    with torch.no_grad():
        out = body(rotmats[:1], shape.reshape(1, -1).to(body.mean_shape), transl=transl[:1])
        x = torch.from_numpy(rest + np.einsum("k,knc->nc", weights[0], targets)).float()
        net = model.apply_blend(x, model.blend(out.transforms))
        post = dresser.resolver(net, out.vertices, body.faces, rest=torch.from_numpy(rest).float())
        blend = blend_transforms(written_weights(model.weights, influences), out.transforms)
        move = torch.linalg.solve(blend[0, :, :, :3].double(),
                                  (post - model.apply_blend(x, blend))[0].double()[..., None])[..., 0]
    return move.float().numpy()


def outfit_animation(body: BodyModel, shape: torch.Tensor, rotmats: torch.Tensor, transl: torch.Tensor, dresser,
                     fps: float = 30.0, tightness=None, influences: int | None = INFLUENCES) -> BlendAnimation:
    """``dresser``'s outfit (resized to ``shape``, ``tightness`` where the outfit has a resizer) on
    the body in the poses ``rotmats`` (T, 24, 3, 3) at ``transl`` (T, 3). Its network must see the
    gravity-aligned pose, i.e. +Y up in the file's frame. The frames' morph targets and weights
    are the garment model's (``GarmentModel.blend_codes``: PBNS's for a pose, NCS's codes for a
    motion where the outfit has one). With T = 1 and a post-step,
    the post-step is one more target at weight 1: the file's cloth is the Dresser's; a motion's
    cloth is the network's (the post-step differs from frame to frame: no blend shape)."""
    shape = shape.reshape(1, -1)
    rotmats, transl = rotmats.detach().float().cpu(), transl.detach().float().cpu().reshape(-1, 3)
    t = len(rotmats)
    rest = dresser.rest_for(body, shape[0], tightness=tightness).numpy()
    model, d, morph = dresser.garment.blend_codes(body, rotmats, shape[0], transl, fps)
    d = d.numpy().reshape(len(d), -1, 3)
    morph = morph.numpy().astype(np.float32)  # (T, |X|)
    if t == 1 and dresser.resolver is not None:  # a photo: the post-step as one more target, weight 1
        d = np.concatenate([d, post_step_target(body, shape, rotmats, transl, dresser, rest, d, morph,
                                                influences)[None]])
        morph = np.concatenate([morph, np.ones((1, 1), np.float32)], 1)
    return BlendAnimation(rest, model.faces.numpy(), model.weights.detach().numpy(), d, morph)
