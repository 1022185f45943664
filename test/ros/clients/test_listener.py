"""The client that only listens (ros/clients/listener.py): what it reports per topic, from the
middleware's receipt and source times of each message. Truth: message times made here, 20 ms
apart when sent and bunched when received (a starved listener)."""
import pytest

from tissue_sim_ros.ros.clients.listener import Arrivals

MS = 1_000_000


def test_the_sent_rate_is_the_publishers_and_the_receipt_rate_what_arrived():
    arrivals = Arrivals()
    assert arrivals.summary() == {'count': 0, 'rate_hz': 0.0, 'sent_rate_hz': 0.0}
    for k in range(51):                                       # sent at 50 Hz for 1 s...
        sent = 5_000 * MS + 20 * MS * k
        received = 5_000 * MS + 500 * MS + 10 * MS * (k // 2) * 2   # ...received in pairs within 0.5 s
        arrivals(None, {'source_timestamp': sent, 'received_timestamp': received})
    summary = arrivals.summary()
    assert summary['count'] == 51
    assert summary['sent_rate_hz'] == pytest.approx(50.0, rel=1e-12)
    assert summary['rate_hz'] == pytest.approx(50 / 0.5, rel=1e-12)


def test_one_message_has_no_rate():
    arrivals = Arrivals()
    arrivals(None, {'source_timestamp': 7, 'received_timestamp': 9})
    assert arrivals.summary() == {'count': 1, 'rate_hz': 0.0, 'sent_rate_hz': 0.0}
