"""Provisioning servo IDs (servo_tool) against the emulated bus."""
import pytest

from hexapod_driver.emulator import BusEmulator
from hexapod_driver.servo_tool import ServoToolError, main, open_port, scan, set_id


@pytest.fixture
def emu_without_7(robot):
    """The emulated bus with no servo at ID 7 (leg3_coxa's): a free ID to provision."""
    with BusEmulator(robot, absent_ids=(7,)) as e:
        yield e


def test_scan_finds_every_servo_with_its_model(emu_without_7):
    port = open_port(emu_without_7.port, 1_000_000, margin_ms=30.0)   # generous: a loaded CI machine must not lose replies
    found = scan(port, range(0, 22), progress=False)
    assert found == [(i, 12) for i in range(1, 19) if i != 7]
    port.closePort()


def test_set_id_renumbers_and_refuses_unsafe_changes(emu_without_7):
    port = open_port(emu_without_7.port, 1_000_000, margin_ms=30.0)   # generous: a loaded CI machine must not lose replies
    with pytest.raises(ServoToolError, match='ID 9 is already taken'):
        set_id(port, 8, 9)
    with pytest.raises(ServoToolError, match='no servo answers at ID 7'):
        set_id(port, 7, 30)
    set_id(port, 8, 7)                                   # leg3_femur's servo takes the free ID 7
    assert emu_without_7.servo_of_joint('leg3_femur').servo_id == 7
    assert emu_without_7.servo_of_joint('leg3_femur').get('id') == 7      # EEPROM register 3
    port.closePort()


def test_command_line_names_the_joint_id_from_the_description(emu_without_7, capsys):
    # leg3_coxa is id 7 in the description; its servo is absent, so the factory-new servo at
    # ID 18 (standing in for a freshly connected one) can take it
    assert main(['--device', emu_without_7.port, 'set-id', '--from', '18', '--joint', 'leg3_coxa']) == 0
    assert 'now has ID 7 (leg3_coxa)' in capsys.readouterr().out
    assert main(['--device', emu_without_7.port, 'set-id', '--from', '18', '--to', '3']) == 1
    assert 'no servo answers at ID 18' in capsys.readouterr().err


def test_bus_options_after_the_sub_command(emu_without_7, capsys):
    """`scan --device X` works like `--device X scan`, and `scan --help` lists it."""
    assert main(['scan', '--device', emu_without_7.port, '--max-id', '20']) == 0
    after = capsys.readouterr().out
    assert main(['--device', emu_without_7.port, 'scan', '--max-id', '20']) == 0
    assert capsys.readouterr().out == after and 'servo(s) found' in after
    with pytest.raises(SystemExit) as e:
        main(['scan', '--help'])
    text = capsys.readouterr().out
    assert e.value.code == 0 and '--device' in text and '--baud' in text and 'default: 253' in text
