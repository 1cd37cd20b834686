"""Stereo pairs of image topics by stereo_image_proc's naming, and --stereo LEFT,RIGHT."""

from __future__ import annotations

import pytest

from replaybench.errors import StereoError
from replaybench.stereo import StereoTopics, find_pairs, parse_stereo
from replaybench.stereo.topics import camera_info_topic


def test_pairs_are_found_by_namespace_preferring_rectified_images_over_raw_ones():
    topics = [
        '/front/left/image_raw',
        '/front/right/image_raw',
        '/front/left/image_rect',
        '/front/right/image_rect',
        '/rear/left/image_rect_color',
        '/rear/right/image_rect_color',
        '/side/left/image_raw',
        '/side/right/image_rect',  # no partner of the same name
        '/camera/image_raw',
    ]
    assert find_pairs(topics) == [
        StereoTopics('/front/left/image_rect', '/front/right/image_rect', True),
        StereoTopics('/rear/left/image_rect_color', '/rear/right/image_rect_color', True),
    ]
    assert find_pairs(['/stereo/left/image_raw', '/stereo/right/image_raw']) == [
        StereoTopics('/stereo/left/image_raw', '/stereo/right/image_raw', False)
    ]
    assert find_pairs(['/left/image_rect', '/right/image_rect'])[0].left_info == '/left/camera_info'


def test_the_camera_info_topic_is_beside_the_image_topic_and_its_transport():
    assert camera_info_topic('/stereo/right/image_rect') == '/stereo/right/camera_info'
    assert camera_info_topic('/a/left/image_raw/compressed') == '/a/left/camera_info'


def test_stereo_option_names_two_topics_and_takes_rectified_from_their_names():
    assert parse_stereo(' /a/left/image_raw , /a/right/image_raw ').rectified is False
    assert parse_stereo('/cam0/image,/cam1/image') == StereoTopics(
        '/cam0/image', '/cam1/image', None
    )


@pytest.mark.parametrize(
    ('text', 'message'),
    [
        ('/a', 'give two image topics, LEFT,RIGHT'),
        ('/a,/b,/c', 'give two image topics'),
        ('/a,', 'give two image topics'),
        ('/a,/a', 'the left and right topics are the same'),
        ('/a,/nope', '--stereo names /nope, not an image topic of the input'),
    ],
)
def test_a_stereo_option_that_names_no_pair_is_one_line(text, message):
    with pytest.raises(StereoError) as err:
        parse_stereo(text, ['/a', '/b', '/c'])
    assert message in str(err.value)
    assert err.value.exit_code == 2
