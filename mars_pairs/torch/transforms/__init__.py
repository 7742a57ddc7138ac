"""Sample transforms that keep the pairing: ground image, chips, masks and keypoints move together.

Every geometric transform is an affine map M from the new image's pixel coordinates to the
old one's (pixel-edge coordinates: a pixel's centre at +0.5). On the ground image it moves
``corr_ground`` by M^-1; on the chips (``ortho``, ``dem``, ``viewshed``, resampled alike:
bilinear, bilinear, nearest) it moves ``corr`` by M^-1 and composes the chip ``transform``
with M, so every keypoint still names the same ground pixel and the same map point, and
``bounds`` and ``rotation`` follow. Colour transforms change pixel values only.

Transforms take one sample dict (``ds[i]``) and return a new one; the input is not changed.
Images may be uint8 (the default transport) or float32; a transform returns the dtype it was
given. Random transforms draw from ``generator`` (default: torch's global generator, which
DataLoader seeds per worker). Keypoints are never dropped: after a crop or a rotation some
fall outside an image, and :func:`keypoints` returns those inside both.

(Written on torch's ``grid_sample`` rather than torchvision's transforms: those do not move
keypoints through arbitrary affine maps nor compose georeferencing, and torchvision is not a
dependency.)
"""

from mars_pairs.torch.transforms.augment import ColorJitter, RandomCrop, RandomFlip, RandomRotate
from mars_pairs.torch.transforms.carry import CarryToChip, CarryToImage
from mars_pairs.torch.transforms.common import Compose, ToFloat, keypoints
from mars_pairs.torch.transforms.geometric import Crop, Flip, NorthUp, Resize, Rotate

__all__ = [
    "CarryToChip",
    "CarryToImage",
    "ColorJitter",
    "Compose",
    "Crop",
    "Flip",
    "NorthUp",
    "RandomCrop",
    "RandomFlip",
    "RandomRotate",
    "Resize",
    "Rotate",
    "ToFloat",
    "keypoints",
]
