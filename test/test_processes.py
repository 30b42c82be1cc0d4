"""How a supervisor (``train``, ``soak``, ``bench``, ``play``) takes signals around its nodes."""
import os
import signal

from pg_node.tools.processes import terminate_as_interrupt
import pytest


@pytest.fixture
def sigint_ignored():
    """Run the test with SIGINT ignored, as ``cmd &`` in a non-interactive shell starts it."""
    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


def test_sigint_inherited_ignored_still_interrupts_and_is_ignored_again_after(sigint_ignored):
    with pytest.raises(KeyboardInterrupt) as caught:
        with terminate_as_interrupt():
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(1000):               # Python runs the handler between bytecodes
                pass
    assert str(caught.value) == ''              # Python's own Ctrl-C, as from a terminal
    assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN


@pytest.mark.parametrize('sig', [signal.SIGTERM, signal.SIGHUP])
def test_sigterm_and_sighup_take_the_ctrl_c_path_naming_the_signal(sig):
    before = signal.getsignal(sig)
    with pytest.raises(KeyboardInterrupt, match=f'signal {sig.name}'):
        with terminate_as_interrupt():
            os.kill(os.getpid(), sig)
            for _ in range(1000):
                pass
    assert signal.getsignal(sig) is before


def test_outside_the_block_sigint_is_as_it_was():
    before = signal.getsignal(signal.SIGINT)
    with terminate_as_interrupt():
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    assert signal.getsignal(signal.SIGINT) is before
