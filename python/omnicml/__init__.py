"""omnicml: omniview-based concurrent map building and localization (appearance SLAM).

Python bindings of the C++ library (pybind11). Images are numpy uint8 arrays of shape
(H, W) (grey) or (H, W, 3) (BGR, OpenCV's order); poses are (x_m, y_m, phi_rad) in the
map or odometry frame; panorama column c looks along robot azimuth 2 pi c / W,
counter-clockwise, row 0 the highest elevation.

    import omnicml
    sim = omnicml.Simulator("home_store", days=1, frames_per_day=100, seed=1, panorama=True)
    engine = omnicml.CmlEngine({"threads": 1})
    engine.begin_session(sim.session(0))
    for frame in sim:
        result = engine.process_frame(frame.image, frame.odom_pose, frame.stamp_s)
        print(result.pose, frame.truth)

Every expected failure (bad file, image, option) raises omnicml.Error (a RuntimeError)
with the library's message; omnicml.InternalError is a broken invariant (a bug).
"""

from ._omnicml import (  # noqa: F401
    ColorHistogram,
    CmlEngine,
    CompareResult,
    Descriptor,
    DescriptorExtractor,
    EngineOptions,
    Error,
    Estimate,
    FourierSignature,
    Frame,
    FrameResult,
    FrameSource,
    InternalError,
    InvariantFeatureHistogram,
    LogReader,
    LogWriter,
    Map,
    OmniCalibration,
    OmniUnwrapper,
    RunResult,
    SessionInfo,
    Simulator,
    auto_calibrate,
    compare,
    evaluate,
    prepare_panorama,
    read_image,
    roll_columns,
    run,
    similarity,
    synthetic_panorama,
    validate_log,
    world_names,
    wrap_angle,
    write_image,
)

def default_options():
    """Every engine option with its default, as a nested dict (the YAML layout)."""
    return EngineOptions().to_dict()


def load_options(path):
    """Engine options from a YAML file (keys equal member names); omnicml.Error names an
    unknown key or invalid value with file and line."""
    return EngineOptions.from_yaml(str(path))


__all__ = [name for name in dir() if not name.startswith("_")]
