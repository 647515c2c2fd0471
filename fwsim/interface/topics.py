"""Every topic and frame name of a run's log, in one place (docs/guide/logs.md says what each carries).

The loop, the flight software's blocks, the metrics, the figures and both
Rerun views name topics from here; nothing else spells them out.
"""
from __future__ import annotations

# -- the harness: the truth, and what the sensors and the camera saw
UAV_STATE = "/uav/state"  # fwsim.interface.messages.AirframeState (JSON)
TF = "/tf"  # foxglove.FrameTransform: uav, camera and ship frames (and uav_estimate) in the world
UAV_POSE = "/uav/pose"  # foxglove.PoseInFrame
SCENE = "/scene"  # foxglove.SceneUpdate: the UAV and ship models, frame-locked (Foxglove's 3D panel)
SCENE_PATHS = "/scene/paths"  # foxglove.SceneUpdate: the flown paths of the UAV and the ship, a segment a second
UAV_FIX = "/uav/fix"  # foxglove.LocationFix: the UAV's latitude, longitude, altitude (Foxglove's map)
TARGET_STATE = "/target/state"  # fwsim.world.target.TargetState
GIMBAL_STATE = "/gimbal/state"  # fwsim.world.gimbal.GimbalState
CAMERA_FRAME = "/camera/frame"  # fwsim.sensors.camera.FrameGeometry: what one frame shows of the ship (truth)
CAMERA_DETECTION = "/camera/detection"  # fwsim.sensors.camera.Detection: the detector's output
CAMERA_IMAGE = "/camera/image"  # foxglove.CompressedImage: rendered frames
CAMERA_CALIBRATION = "/camera/calibration"  # foxglove.CameraCalibration
CAMERA_ANNOTATIONS = "/camera/annotations"  # foxglove.ImageAnnotations: boxes over each /camera/image
AUTOPILOT_COMMAND = "/autopilot/command"  # RateCommand | AccelCommand from the flight software
AUTOPILOT_STATUS = "/autopilot/status"  # the inner loops' set-points
ACTUATORS = "/actuators"  # ActuatorCommand
EVENTS = "/events"  # foxglove.Log: phase switches, lock, warnings, the end of the run
WORLD_AIR = "/world/air"  # fwsim.interface.messages.AirState: the air's velocity (wind, gusts, turbulence), when not still

# -- the flight software (controllers/)
NAV_ESTIMATE = "/nav/estimate"  # fwsim.interface.messages.NavEstimate: the onboard navigation filter's estimate
NAV_POSE = "/nav/pose"  # foxglove.PoseInFrame: that estimate's pose (on /tf: uav_estimate), once initialised
NAV_AID_PREFIX = "/nav/aid/"  # + source: fwsim.interface.messages.AidSourceStatus, one per fusion attempt
FSW_STATUS = "/fsw/status"  # FlightSoftwareStatus, every tick
FSW_GIMBAL_COMMAND = "/fsw/gimbal_command"  # GimbalCommand
FSW_ESTIMATE = "/fsw/estimate"  # controllers.messages.TargetEstimate
FSW_ESTIMATOR_STATUS = "/fsw/estimator_status"  # controllers.messages.EstimatorStatus, when a counter changes
FSW_DETECTION_FUSION = "/fsw/detection_fusion"  # controllers.messages.DetectionFusion, one per detection
FSW_SHIP_HEADING = "/fsw/ship_heading"  # controllers.perception.target_model.ShipHeadingStatus
FSW_COURSE_TURN = "/fsw/course_turn"  # estimation.course_turn.CourseTurnStatus (controllers.turn_from_course on)
FSW_IBVS = "/fsw/ibvs"  # controllers.pointing.ibvs.IbvsStatus
FSW_NMPC = "/fsw/nmpc"  # controllers.guidance.nmpc.NmpcStatus, one per solve
FSW_BPNG = "/fsw/bpng"  # controllers.guidance.bpng.BpngStatus

# -- frames of the transforms
WORLD_FRAME = "world"
UAV_FRAME = "uav"
UAV_ESTIMATE_FRAME = "uav_estimate"  # the navigation filter's estimate of the uav frame
CAMERA_FRAME_ID = "camera"
SHIP_FRAME_ID = "ship"
