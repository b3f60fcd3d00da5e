"""Readers and writers of recording and result files.

Sensor recordings (skeleton input): bonefit sensor CSV, tracker ASCII, NPZ.
Kinematics recordings (translation input): kinematics CSV, BVH + accelerations, Xsens MVNX.
Results: skeleton JSON/CSV/BVH/NPZ; translation JSON/CSV/BVH/MVNX/NPZ.
"""

from typing import TYPE_CHECKING

from .._lazy import lazy_attributes

if TYPE_CHECKING:
    from .kinematics import (
        KinematicsRecording,
        read_kinematics,
        sniff_kinematics,
        translation_to_dict,
        write_kinematics_csv,
        write_translation,
    )
    from .result_json import (
        offsets_from_dict,
        offsets_to_dict,
        result_from_dict,
        skeleton_from_dict,
        translation_from_dict,
    )
    from .sensors import (
        RowCounter,
        example_path,
        read_recording,
        sniff_recording,
        write_sensor_csv,
        write_sensor_npz,
    )
    from .skeleton import (
        read_skeleton_json,
        read_skeleton_npz,
        read_skeleton_offsets,
        skeleton_to_bvh,
        skeleton_to_dict,
        write_skeleton_bvh,
        write_skeleton_csv,
        write_skeleton_json,
        write_skeleton_npz,
    )
    from .tracker import (
        TrackerLayout,
        detect_tracker_layout,
        parse_stations,
        parse_tracker_layout,
        read_tracker_ascii,
    )

__all__ = [
    "KinematicsRecording",
    "RowCounter",
    "TrackerLayout",
    "detect_tracker_layout",
    "example_path",
    "offsets_from_dict",
    "offsets_to_dict",
    "parse_stations",
    "parse_tracker_layout",
    "read_kinematics",
    "read_recording",
    "read_skeleton_json",
    "read_skeleton_npz",
    "read_skeleton_offsets",
    "read_tracker_ascii",
    "result_from_dict",
    "skeleton_from_dict",
    "skeleton_to_bvh",
    "skeleton_to_dict",
    "sniff_kinematics",
    "sniff_recording",
    "translation_from_dict",
    "translation_to_dict",
    "write_kinematics_csv",
    "write_sensor_csv",
    "write_sensor_npz",
    "write_skeleton_bvh",
    "write_skeleton_csv",
    "write_skeleton_json",
    "write_skeleton_npz",
    "write_translation",
]

# names above are imported from their submodule on first use (see _lazy)
__getattr__, __dir__ = lazy_attributes(__name__, {
    "kinematics": ("KinematicsRecording", "read_kinematics", "sniff_kinematics",
                   "translation_to_dict", "write_kinematics_csv", "write_translation"),
    "sensors": ("RowCounter", "example_path", "read_recording",
                "sniff_recording", "write_sensor_csv", "write_sensor_npz"),
    "tracker": ("TrackerLayout", "detect_tracker_layout", "parse_stations",
                "parse_tracker_layout", "read_tracker_ascii"),
    "result_json": ("offsets_from_dict", "offsets_to_dict", "result_from_dict",
                    "skeleton_from_dict", "translation_from_dict"),
    "skeleton": ("read_skeleton_json", "read_skeleton_npz", "read_skeleton_offsets",
                 "skeleton_to_bvh", "skeleton_to_dict", "write_skeleton_bvh",
                 "write_skeleton_csv", "write_skeleton_json", "write_skeleton_npz"),
})
