# SPDX-License-Identifier: Apache-2.0
"""Default topic names and frame ids (docs/interfaces.md), one place for nodes, simulator and evaluator."""

LEFT_FRAME = "left_camera_optical_frame"
RIGHT_FRAME = "right_camera_optical_frame"

LEFT_IMAGE = "/stereo/left/image_rect"
RIGHT_IMAGE = "/stereo/right/image_rect"
LEFT_CAMERA_INFO = "/stereo/left/camera_info"
RIGHT_CAMERA_INFO = "/stereo/right/camera_info"
TIP_HINT = "/suture/tip_hint"

LEFT_MASK = "/suture/left/mask"
RIGHT_MASK = "/suture/right/mask"
#: The masks at segmentation_node's lower (hysteresis) threshold, for ordering_node
#: (docs/interfaces.md, "Topics").
LEFT_MASK_LOW = "/suture/left/mask_low"
RIGHT_MASK_LOW = "/suture/right/mask_low"
LEFT_SEQUENCE = "/suture/left/sequence"
RIGHT_SEQUENCE = "/suture/right/sequence"
POINTS = "/suture/points"
PATH = "/suture/path"
GRASP_POSE = "/suture/grasp_pose"
MARKERS = "/suture/markers"

GT_LEFT_MASK = "/ground_truth/left/mask"
GT_RIGHT_MASK = "/ground_truth/right/mask"
GT_LEFT_SEQUENCE = "/ground_truth/left/sequence"
GT_RIGHT_SEQUENCE = "/ground_truth/right/sequence"
GT_PATH = "/ground_truth/path"
GT_GRASP_POSE = "/ground_truth/grasp_pose"
GT_TOPOLOGY = "/ground_truth/topology"

#: Topics a pipeline consumes from a recorded or simulated bag.
INPUT_TOPICS = (LEFT_IMAGE, RIGHT_IMAGE, LEFT_CAMERA_INFO, RIGHT_CAMERA_INFO, TIP_HINT)
#: Ground-truth topics written by the simulator, with the stamps of the images.
GROUND_TRUTH_TOPICS = (
    GT_LEFT_MASK,
    GT_RIGHT_MASK,
    GT_LEFT_SEQUENCE,
    GT_RIGHT_SEQUENCE,
    GT_PATH,
    GT_GRASP_POSE,
    GT_TOPOLOGY,
)

#: Outputs of grasp_executor (its node defines the same names; docs/interfaces.md, "Topics").
TARGET_POSE = "/grasp_executor/target_pose"
EXECUTOR_STATE = "/grasp_executor/state"

#: Everything the running pipeline publishes: what a recorder keeps by default.
PIPELINE_OUTPUT_TOPICS = (
    LEFT_MASK,
    RIGHT_MASK,
    LEFT_MASK_LOW,
    RIGHT_MASK_LOW,
    LEFT_SEQUENCE,
    RIGHT_SEQUENCE,
    POINTS,
    PATH,
    GRASP_POSE,
    MARKERS,
    TARGET_POSE,
    EXECUTOR_STATE,
)

#: Full message type name of every docs/interfaces.md topic (inputs, pipeline outputs, ground truth).
TOPIC_TYPES: dict[str, str] = {
    LEFT_IMAGE: "sensor_msgs/msg/Image",
    RIGHT_IMAGE: "sensor_msgs/msg/Image",
    LEFT_CAMERA_INFO: "sensor_msgs/msg/CameraInfo",
    RIGHT_CAMERA_INFO: "sensor_msgs/msg/CameraInfo",
    TIP_HINT: "geometry_msgs/msg/PointStamped",
    LEFT_MASK: "sensor_msgs/msg/Image",
    RIGHT_MASK: "sensor_msgs/msg/Image",
    LEFT_MASK_LOW: "sensor_msgs/msg/Image",
    RIGHT_MASK_LOW: "sensor_msgs/msg/Image",
    LEFT_SEQUENCE: "geometry_msgs/msg/PolygonStamped",
    RIGHT_SEQUENCE: "geometry_msgs/msg/PolygonStamped",
    POINTS: "sensor_msgs/msg/PointCloud2",
    PATH: "nav_msgs/msg/Path",
    GRASP_POSE: "geometry_msgs/msg/PoseStamped",
    MARKERS: "visualization_msgs/msg/MarkerArray",
    TARGET_POSE: "geometry_msgs/msg/PoseStamped",
    EXECUTOR_STATE: "std_msgs/msg/String",
    GT_LEFT_MASK: "sensor_msgs/msg/Image",
    GT_RIGHT_MASK: "sensor_msgs/msg/Image",
    GT_LEFT_SEQUENCE: "geometry_msgs/msg/PolygonStamped",
    GT_RIGHT_SEQUENCE: "geometry_msgs/msg/PolygonStamped",
    GT_PATH: "nav_msgs/msg/Path",
    GT_GRASP_POSE: "geometry_msgs/msg/PoseStamped",
    GT_TOPOLOGY: "std_msgs/msg/String",
}
