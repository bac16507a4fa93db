"""Protocol 1.0 packets: byte-exact examples from the AX-12A manual, parser resynchronisation."""
import pytest

from hexapod_driver import protocol as p


def test_ping_example_from_the_manual():
    # e-manual: PING to ID 1 is FF FF 01 02 01 FB; the status packet is FF FF 01 02 00 FC
    assert p.encode_instruction(1, p.PING) == bytes.fromhex('ffff010201fb')
    assert p.encode_status(1, 0) == bytes.fromhex('ffff010200fc')


def test_read_temperature_example_from_the_manual():
    # READ 1 byte at 0x2B (present temperature) of ID 1: FF FF 01 04 02 2B 01 CC;
    # answer 32 deg C: FF FF 01 03 00 20 DB
    assert p.encode_instruction(1, p.READ, [0x2B, 1]) == bytes.fromhex('ffff0104022b01cc')
    pkt = p.decode_packet(bytes.fromhex('ffff01030020db'))
    assert (pkt.servo_id, pkt.code, pkt.params, pkt.checksum_ok) == (1, 0, b'\x20', True)


def test_checksum_is_the_inverted_low_byte_of_the_sum():
    body = [0xFE, 0x04, 0x03, 0x03, 0x01]          # broadcast WRITE id := 1
    assert p.checksum(body) == (~sum(body)) & 0xFF == 0xF6
    assert p.decode_packet(bytes([0xFF, 0xFF, *body, 0xF7])).checksum_ok is False


@pytest.mark.parametrize('raw, what', [
    (b'\xff\xff\x01', 'too short'),
    (b'\xfe\xff\x01\x02\x01\xfb', '0xFF 0xFF'),
    (b'\xff\xff\x01\x05\x01\xfb', 'LENGTH byte says'),
])
def test_decode_rejects_malformed_packets_with_a_reason(raw, what):
    with pytest.raises(p.ProtocolError, match=what):
        p.decode_packet(raw)


def test_encode_rejects_non_bytes():
    with pytest.raises(p.ProtocolError, match='servo id'):
        p.encode_instruction(300, p.PING)
    with pytest.raises(p.ProtocolError, match='parameter'):
        p.encode_instruction(1, p.WRITE, [30, -1])


def test_parser_resynchronises_on_garbage_and_split_packets():
    a = p.encode_instruction(3, p.READ, [36, 2])
    b = p.encode_instruction(4, p.WRITE, [30, 0, 2])
    stream = b'\x00\x13\xff' + a + b'\xff\xff\xff' + b
    parser = p.PacketParser()
    out = []
    for k in range(len(stream)):                      # one byte at a time
        out += list(parser.feed(stream[k:k + 1]))
    assert [(x.servo_id, x.code, x.params) for x in out] == [(3, p.READ, b'\x24\x02'), (4, p.WRITE, b'\x1e\x00\x02')]
    assert all(x.checksum_ok for x in out)
    assert parser.pending == 0 and parser.discarded_bytes == 6   # 00 13 FF before a, FF FF FF before b


def test_control_table_layout():
    assert [(r.address, r.size) for r in p.CONTROL_TABLE if r.name in
            ('goal_position', 'present_position', 'present_load', 'torque_limit', 'return_delay_time')] == \
        [(5, 1), (30, 2), (34, 2), (36, 2), (40, 2)]
    assert all(r.area == p.EEPROM for r in p.CONTROL_TABLE if r.address < 24)
    assert all(r.area == p.RAM for r in p.CONTROL_TABLE if r.address >= 24)
    assert p.BYTE_MAP[31] == (p.REGISTERS['goal_position'], 1)
    assert 10 not in p.BYTE_MAP                       # reserved address


def test_load_and_speed_encoding():
    assert p.decode_load(p.encode_load(0.5)) == pytest.approx(0.5, abs=1e-3)
    assert p.decode_load(p.encode_load(-0.25)) == pytest.approx(-0.25, abs=1e-3)
    assert p.encode_load(-1.0) == 0x400 | 1023
    assert p.encode_speed(-10) == 0x400 | 10


def test_register_words_are_little_endian_and_found_by_name_in_a_block():
    # e-manual: goal position 0x200 is written as 00 02 (low byte first)
    assert p.word(0x200) == [0x00, 0x02] and p.u16(bytes([0x00, 0x02])) == 0x200
    block = bytes([1, 0, 0, 0, 0, 0, *p.word(512), *p.word(0), *p.word(1023), *p.word(700), 0, 0,
                   *p.word(p.encode_load(-0.5)), 121, 38])          # a READ of 24..43
    assert p.register_value(block, 24, 'torque_enable') == 1
    assert p.register_value(block, 24, 'torque_limit') == 1023
    assert p.register_value(block, 24, 'present_position') == 700
    assert p.decode_load(p.register_value(block, 24, 'present_load')) == pytest.approx(-0.5, abs=1e-3)
    assert p.register_value(block, 24, 'present_temperature') == 38
    with pytest.raises(p.ProtocolError, match='punch'):
        p.register_value(block, 24, 'punch')                   # past the end of the block
    with pytest.raises(p.ProtocolError, match='model_number'):
        p.register_value(block, 24, 'model_number')            # before its start


def test_bus_time_of_a_position_read_at_1mbps():
    # (8 + 8 bytes) x 10 bits at 1 Mbps = 160 us; return delay 250 (x 2 us) adds 500 us
    assert p.read_bus_time_s(2, 1_000_000, 0.0) == pytest.approx(160e-6)
    assert p.read_bus_time_s(2, 1_000_000, 250 * p.RETURN_DELAY_UNIT_S) == pytest.approx(660e-6)
    assert p.baud_of_register(1) == 1_000_000
    assert p.sync_write_bytes(18, 2) == 8 + 18 * 3


def test_error_bit_masks_of_the_diagnostics_are_the_protocols():
    """/diagnostics names error bits with hexapod_model.diagnostics' table: the same masks."""
    pytest.importorskip('rclpy')
    from hexapod_driver import protocol
    from hexapod_model import diagnostics as dg
    from hexapod_msgs.msg import ServoStatus
    for bit, (name, _) in dg.ERROR_BITS.items():
        const = 'ERR_' + name.upper().replace(' ', '_')
        assert getattr(ServoStatus, const) == bit and getattr(protocol, const) == bit
def test_error_bits_are_the_servo_modules():
    """The status bits are defined once, with the servo in hexapod_model; the protocol re-exports them."""
    from hexapod_model import servo
    for n in (n for n in dir(servo) if n.startswith('ERR_')):
        assert getattr(p, n) is getattr(servo, n), n
    assert p.describe_error is servo.describe_error
