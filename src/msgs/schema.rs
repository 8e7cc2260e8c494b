//! `ros2msg` schema texts exactly as rosbag2 / rosbags write them into MCAP schema records:
//! the type's comment-free definition, then each dependency (depth-first, first use order)
//! after a line of 80 `=` and a `MSG: pkg/Type` line.

/// Comment-free `.msg` definitions by type.
macro_rules! def {
    (Time) => { "int32 sec\nuint32 nanosec\n" };
    (Header) => { "builtin_interfaces/Time stamp\nstring frame_id\n" };
    (Image) => { "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\nuint32 step\nuint8[] data\n" };
    (CompressedImage) => { "std_msgs/Header header\nstring format\nuint8[] data\n" };
    (RegionOfInterest) => { "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n" };
    (CameraInfo) => { "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\nfloat64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\nuint32 binning_y\nsensor_msgs/RegionOfInterest roi\n" };
    (PointField) => { "uint8 INT8=1\nuint8 UINT8=2\nuint8 INT16=3\nuint8 UINT16=4\nuint8 INT32=5\nuint8 UINT32=6\nuint8 FLOAT32=7\nuint8 FLOAT64=8\nstring name\nuint32 offset\nuint8 datatype\nuint32 count\n" };
    (PointCloud2) => { "std_msgs/Header header\nuint32 height\nuint32 width\nsensor_msgs/PointField[] fields\nbool is_bigendian\nuint32 point_step\nuint32 row_step\nuint8[] data\nbool is_dense\n" };
    (Point) => { "float64 x\nfloat64 y\nfloat64 z\n" };
    (Vector3) => { "float64 x\nfloat64 y\nfloat64 z\n" };
    (Quaternion) => { "float64 x\nfloat64 y\nfloat64 z\nfloat64 w\n" };
    (Pose) => { "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n" };
    (PoseStamped) => { "std_msgs/Header header\ngeometry_msgs/Pose pose\n" };
    (PoseWithCovariance) => { "geometry_msgs/Pose pose\nfloat64[36] covariance\n" };
    (PoseWithCovarianceStamped) => { "std_msgs/Header header\ngeometry_msgs/PoseWithCovariance pose\n" };
    (Transform) => { "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n" };
    (TransformStamped) => { "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform\n" };
    (TFMessage) => { "geometry_msgs/TransformStamped[] transforms\n" };
    (KeyValue) => { "string key\nstring value\n" };
    (DiagnosticStatus) => { "byte OK=0\nbyte WARN=1\nbyte ERROR=2\nbyte STALE=3\nbyte level\nstring name\nstring message\nstring hardware_id\ndiagnostic_msgs/KeyValue[] values\n" };
    (DiagnosticArray) => { "std_msgs/Header header\ndiagnostic_msgs/DiagnosticStatus[] status\n" };
    (Correspondence) => { "float32 u\nfloat32 v\nfloat32 x\nfloat32 y\nfloat32 z\nfloat32 score\n" };
    (Correspondences) => { "std_msgs/Header header\nstring map_frame_id\nangle_i2p_msgs/Correspondence[] correspondences\n" };
}

/// One dependency section of a schema.
macro_rules! dep {
    ($name:literal, $ty:ident) => {
        concat!(
            "================================================================================\nMSG: ",
            $name,
            "\n",
            def!($ty)
        )
    };
}

pub const TIME: &str = def!(Time);
pub const HEADER: &str = concat!(def!(Header), dep!("builtin_interfaces/Time", Time));
pub const IMAGE: &str = concat!(def!(Image), dep!("std_msgs/Header", Header), dep!("builtin_interfaces/Time", Time));
pub const COMPRESSED_IMAGE: &str =
    concat!(def!(CompressedImage), dep!("std_msgs/Header", Header), dep!("builtin_interfaces/Time", Time));
pub const REGION_OF_INTEREST: &str = def!(RegionOfInterest);
pub const CAMERA_INFO: &str = concat!(
    def!(CameraInfo),
    dep!("std_msgs/Header", Header),
    dep!("builtin_interfaces/Time", Time),
    dep!("sensor_msgs/RegionOfInterest", RegionOfInterest)
);
pub const POINT_FIELD: &str = def!(PointField);
pub const POINT_CLOUD2: &str = concat!(
    def!(PointCloud2),
    dep!("std_msgs/Header", Header),
    dep!("builtin_interfaces/Time", Time),
    dep!("sensor_msgs/PointField", PointField)
);
pub const POINT: &str = def!(Point);
pub const VECTOR3: &str = def!(Vector3);
pub const QUATERNION: &str = def!(Quaternion);
pub const POSE: &str =
    concat!(def!(Pose), dep!("geometry_msgs/Point", Point), dep!("geometry_msgs/Quaternion", Quaternion));
pub const POSE_STAMPED: &str = concat!(
    def!(PoseStamped),
    dep!("std_msgs/Header", Header),
    dep!("builtin_interfaces/Time", Time),
    dep!("geometry_msgs/Pose", Pose),
    dep!("geometry_msgs/Point", Point),
    dep!("geometry_msgs/Quaternion", Quaternion)
);
pub const POSE_WITH_COVARIANCE: &str = concat!(
    def!(PoseWithCovariance),
    dep!("geometry_msgs/Pose", Pose),
    dep!("geometry_msgs/Point", Point),
    dep!("geometry_msgs/Quaternion", Quaternion)
);
pub const POSE_WITH_COVARIANCE_STAMPED: &str = concat!(
    def!(PoseWithCovarianceStamped),
    dep!("std_msgs/Header", Header),
    dep!("builtin_interfaces/Time", Time),
    dep!("geometry_msgs/PoseWithCovariance", PoseWithCovariance),
    dep!("geometry_msgs/Pose", Pose),
    dep!("geometry_msgs/Point", Point),
    dep!("geometry_msgs/Quaternion", Quaternion)
);
pub const TRANSFORM: &str =
    concat!(def!(Transform), dep!("geometry_msgs/Vector3", Vector3), dep!("geometry_msgs/Quaternion", Quaternion));
pub const TRANSFORM_STAMPED: &str = concat!(
    def!(TransformStamped),
    dep!("std_msgs/Header", Header),
    dep!("builtin_interfaces/Time", Time),
    dep!("geometry_msgs/Transform", Transform),
    dep!("geometry_msgs/Vector3", Vector3),
    dep!("geometry_msgs/Quaternion", Quaternion)
);
pub const TF_MESSAGE: &str = concat!(
    def!(TFMessage),
    dep!("geometry_msgs/TransformStamped", TransformStamped),
    dep!("std_msgs/Header", Header),
    dep!("builtin_interfaces/Time", Time),
    dep!("geometry_msgs/Transform", Transform),
    dep!("geometry_msgs/Vector3", Vector3),
    dep!("geometry_msgs/Quaternion", Quaternion)
);
pub const KEY_VALUE: &str = def!(KeyValue);
pub const DIAGNOSTIC_STATUS: &str = concat!(def!(DiagnosticStatus), dep!("diagnostic_msgs/KeyValue", KeyValue));
pub const DIAGNOSTIC_ARRAY: &str = concat!(
    def!(DiagnosticArray),
    dep!("std_msgs/Header", Header),
    dep!("builtin_interfaces/Time", Time),
    dep!("diagnostic_msgs/DiagnosticStatus", DiagnosticStatus),
    dep!("diagnostic_msgs/KeyValue", KeyValue)
);
pub const CORRESPONDENCE: &str = def!(Correspondence);
pub const CORRESPONDENCES: &str = concat!(
    def!(Correspondences),
    dep!("std_msgs/Header", Header),
    dep!("builtin_interfaces/Time", Time),
    dep!("angle_i2p_msgs/Correspondence", Correspondence)
);
