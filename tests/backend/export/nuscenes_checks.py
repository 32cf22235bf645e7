"""What a nuScenes export must give nuscenes-devkit's evaluation (shared by test_nuscenes.py and the surround demo's
test): the ground truth built as the devkit's ``load_gt`` builds it, through its own ``filter_eval_boxes``."""

import numpy as np


def evaluation_filter(nusc) -> tuple:
    """(inserted, kept_inserted, kept): the annotations marked ``synthetic``, those of them the devkit's
    ``filter_eval_boxes`` (detection_cvpr_2019 class ranges, the 0-LiDAR-point drop) keeps, and all it keeps."""
    from nuscenes.eval.common.config import config_factory
    from nuscenes.eval.common.data_classes import EvalBoxes
    from nuscenes.eval.common.loaders import add_center_dist, filter_eval_boxes
    from nuscenes.eval.detection.data_classes import DetectionBox
    from nuscenes.eval.detection.utils import category_to_detection_name

    boxes, inserted = EvalBoxes(), 0
    for s in nusc.sample:   # the ground truth as load_gt builds it (its split is by the devkit's scene names)
        gt = []
        for ann in s["anns"]:
            rec = nusc.get("sample_annotation", ann)
            attrs = [nusc.get("attribute", t)["name"] for t in rec["attribute_tokens"]]
            name = category_to_detection_name(rec["category_name"])
            if name is None:   # load_gt leaves out what no detection class covers
                continue
            gt.append(DetectionBox(s["token"], rec["translation"], rec["size"], rec["rotation"],
                                   nusc.box_velocity(ann)[:2], num_pts=rec["num_lidar_pts"] + rec["num_radar_pts"],
                                   detection_name=name, attribute_name=attrs[0] if attrs else ""))
            inserted += bool(rec.get("synthetic"))
        boxes.add_boxes(s["token"], gt)
    boxes = filter_eval_boxes(nusc, add_center_dist(nusc, boxes), config_factory("detection_cvpr_2019").class_range)
    kept = [bool(nusc.get("sample_annotation", ann).get("synthetic")) for s in nusc.sample for ann in s["anns"]
            if any(np.allclose(b.translation, nusc.get("sample_annotation", ann)["translation"])
                   for b in boxes[s["token"]])]
    return inserted, sum(kept), len(kept)
