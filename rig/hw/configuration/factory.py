"""The configuration source a rig config selects (`configuration.source:`), made without the simulator.

`operator`, `file` and `camera` are made here; `command` is no source at all (None: the commanded
angles stand in for the measured ones, as before); `simulator` is made by the simulated rig, which
owns the world it measures. The camera source lives in an optional extra: its module is imported
only when a config selects it, so a rig without OpenCV installed never imports it.
"""

from __future__ import annotations

import importlib
from typing import assert_never, cast

from rig.errors import ConfigError
from rig.hw.configuration.file_source import FileConfigurationSource, MeasuredAnglesFile
from rig.hw.configuration.operator_source import OperatorConfigurationSource
from rig.hw.seams import Clock, ConfigurationSource
from rig.inputs.rig_config import RigConfig, configuration_source_kind
from rig.vocabulary import ConfigurationSourceKind

# The camera source (the `camera` extra, rig/hw/camera/): these modules are imported only when a
# config selects `source: camera`, so OpenCV is never imported otherwise.
CAMERA_PACKAGE = "rig.hw.camera"


def sees_slips(kind: ConfigurationSourceKind) -> bool:
    """Whether a source can tell which joint moved in a slip (measured again after it)."""
    match kind:
        case (
            ConfigurationSourceKind.SIMULATOR
            | ConfigurationSourceKind.CAMERA
            | ConfigurationSourceKind.OPERATOR
        ):
            return True
        case ConfigurationSourceKind.FILE | ConfigurationSourceKind.COMMAND:
            return False
        case _:
            assert_never(kind)


def hardware_configuration_source(config: RigConfig, clock: Clock) -> ConfigurationSource | None:
    """The source of a config's `configuration:` section (None for `command`)."""
    kind = configuration_source_kind(config)
    section = config.configuration
    lengths = config.article.segment_lengths_m
    match kind:
        case ConfigurationSourceKind.COMMAND:
            return None
        case ConfigurationSourceKind.OPERATOR:
            return OperatorConfigurationSource(lengths, clock)
        case ConfigurationSourceKind.FILE:
            assert section.file is not None  # the parser requires it
            table = MeasuredAnglesFile.load(section.file, config.article.joint_count)
            return FileConfigurationSource(table, lengths, clock)
        case ConfigurationSourceKind.CAMERA:
            return camera_configuration_source(config, clock)
        case ConfigurationSourceKind.SIMULATOR:
            raise ConfigError(f"{config.source}: configuration.source: simulator needs kind: simulated")
        case _:
            assert_never(kind)


def camera_configuration_source(config: RigConfig, clock: Clock) -> ConfigurationSource:
    """The camera source of the optional extra, imported now (a clear error when it is not installed).

    Frames come from the device index `configuration.device`; the calibration and the marker map
    are read and checked here, before anything moves.
    """
    section = config.configuration
    try:
        source = importlib.import_module(f"{CAMERA_PACKAGE}.source")
        calibration = importlib.import_module(f"{CAMERA_PACKAGE}.camera_calibration")
        marker_map = importlib.import_module(f"{CAMERA_PACKAGE}.marker_map")
    except ImportError as exc:
        raise ConfigError(
            f"{config.source}: configuration.source: camera needs the camera extra "
            f"(pip install -e '.[camera]'): {exc}"
        ) from None
    made = source.CameraConfigurationSource(
        source.CameraDevice(section.device),
        calibration.load_calibration(section.camera),
        marker_map.load_marker_map(section.markers),
        clock,
    )
    return cast(ConfigurationSource, made)
