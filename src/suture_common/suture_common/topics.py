"""Default topic names and frame ids of DESIGN.md, in one place for nodes, simulator and evaluator."""

LEFT_FRAME = "left_camera_optical_frame"
RIGHT_FRAME = "right_camera_optical_frame"

LEFT_IMAGE = "/stereo/left/image_rect"
RIGHT_IMAGE = "/stereo/right/image_rect"
LEFT_CAMERA_INFO = "/stereo/left/camera_info"
RIGHT_CAMERA_INFO = "/stereo/right/camera_info"
TIP_HINT = "/suture/tip_hint"

LEFT_MASK = "/suture/left/mask"
RIGHT_MASK = "/suture/right/mask"
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
