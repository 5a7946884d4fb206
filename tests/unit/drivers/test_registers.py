"""The register layout of a Modbus length: encoding and word order round trip, bad encodings refused."""

import pytest

from drivers.drawstring import RegisterMap


@pytest.mark.parametrize("encoding", ["int32_um", "float32_mm"])
@pytest.mark.parametrize("word_order", ["big", "little"])
def test_register_encoding_round_trips(encoding, word_order):
    regs = RegisterMap(encoding=encoding, word_order=word_order, scale=0.5)
    for length in (0.0, 1234.567, -0.001, 1999.999):
        assert regs.decode_mm(regs.encode_mm(length)) == pytest.approx(length, abs=1e-4)
    with pytest.raises(ValueError, match="encoding must be one of"):
        RegisterMap(encoding="int16_mm")
