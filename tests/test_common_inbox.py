"""An inbox keeps a topic's messages in DDS until the node pulls them, in order."""

import time

from conftest import wait_for
from std_msgs.msg import String
from ur_rg2_common.inbox import Inbox


def test_messages_wait_for_a_pull_and_come_in_order_with_their_arrival(ros_graph):
    node = ros_graph.node('inbox_owner')
    handled = []
    inbox = Inbox(node, String, 'news', 10,
                  lambda message, arrival: handled.append((message.data, arrival)))
    publisher = ros_graph.node('inbox_sender').create_publisher(String, 'news', 10)
    wait_for(lambda: publisher.get_subscription_count() == 1, 10, 'the inbox to subscribe')

    sent = time.monotonic()
    for n in range(3):
        publisher.publish(String(data=str(n)))
    time.sleep(0.5)  # the executor spins meanwhile, and leaves them alone
    assert handled == []
    wait_for(lambda: inbox.pull() >= 0 and len(handled) == 3, 10, 'the three messages')
    pulled = time.monotonic()
    assert [data for data, _ in handled] == ['0', '1', '2']
    assert [arrival.sequence for _, arrival in handled] == [1, 2, 3]
    assert all(sent - 0.05 <= arrival.received <= pulled for _, arrival in handled)
    assert inbox.pull() == 0


def test_a_shallow_inbox_keeps_the_newest(ros_graph):
    node = ros_graph.node('inbox_owner')
    handled = []
    inbox = Inbox(node, String, 'news', 1, lambda message, _: handled.append(message.data))
    publisher = ros_graph.node('inbox_sender').create_publisher(String, 'news', 10)
    wait_for(lambda: publisher.get_subscription_count() == 1, 10, 'the inbox to subscribe')

    for n in range(5):
        publisher.publish(String(data=str(n)))
    time.sleep(0.5)  # all five come meanwhile
    wait_for(lambda: inbox.pull() >= 0 and '4' in handled, 10, 'the last message')
    assert handled == ['4']
