import pytest

from camnet.bus import keys
from camnet.errors import InputError


def test_keys_layout():
    assert keys.frame("sim", "left") == "camnet/sim/cam/left/frame"
    assert keys.observations("sim") == "camnet/sim/observations"
    assert keys.calibration("sim") == "camnet/sim/calibration"
    assert keys.groundtruth("sim") == "camnet/sim/groundtruth"
    assert keys.node("sim", "driver", "left") == "camnet/sim/nodes/driver/left"
    assert keys.node_stats("sim", "driver", "left") == "camnet/sim/nodes/driver/left/stats"
    assert keys.parse_node("camnet/sim/nodes/driver/left") == ("sim", "driver", "left")
    assert keys.parse_frame(keys.frame("r", "c")) == ("r", "c")
    assert keys.calibrator("sim", "4ba47ec6") == "camnet/sim/calibrator/4ba47ec6"
    assert keys.parse_calibrator(keys.calibrator("r", "4ba47ec6")) == ("r", "4ba47ec6")


@pytest.mark.parametrize("bad", ["a/b", "a*", "$x", "q?", "h#", "", " x"])
def test_bad_ids_refused(bad):
    with pytest.raises(InputError, match="camera id"):
        keys.frame("sim", bad)
