"""Synthetic label writers: an Observation -> a PDS3 or PDS4 label that the readers accept.

The labels use the real keywords, element names, namespaces and structure of Curiosity
Mastcam (PDS3) and Perseverance Mastcam-Z (PDS4) products, so that synthetic missions go
through the same reader code paths as real data: PDS3 with ``MSL:`` keywords, an
IMAGE_REQUEST_PARMS group whose LINES/LINE_SAMPLES are not the product's, and the IMAGE
object; PDS4 with several ``geom:Coordinate_Space_Definition`` blocks, two
``geom:Derived_Geometry`` blocks (ROVER_NAV_FRAME first, SITE_FRAME second) and the image
array axes. PDS3 labels come in two styles: Mastcam RDR ("mastcam") and MIPL ("mipl":
GEOMETRIC_CAMERA_MODEL, ROVER_COORDINATE_SYSTEM, SITE_DERIVED_GEOMETRY_PARMS), detached or
attached to an IMG (``write_pds3_img``); PDS4 labels can write their IMG beside them. Camera
models: CAHV, CAHVOR and CAHVORE. Values that the Observation does not carry (request window,
RSM head frame) are marked as synthetic in the label. Writers raise ArgumentError (a
ValueError) for values no label can hold.
"""

from mars_pairs.synth.labels.pds3 import write_pds3_img, write_pds3_label
from mars_pairs.synth.labels.pds4 import write_pds4_label

__all__ = ["write_pds3_img", "write_pds3_label", "write_pds4_label"]
