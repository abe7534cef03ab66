/* A ROS 2 peer in C on Cyclone DDS's C library (Debian's 0.10.x, the series ROS 2 Humble's rmw_cyclonedds uses),
   with the types of ros2_msgs.idl: the ROS 2 test's interop check (tests/cli/test_ros2_node.py).

     peer publish ROWS SUBSCRIBERS   JointState on rt/joint_states: ROWS' first line the joint names, then one line
                                     per message "stamp_ns p1 ... pN"; paced by the stamps (the stamp also its source
                                     timestamp) once SUBSCRIBERS readers match
     peer record TOPIC FILE          each std_msgs/String on rt/TOPIC a line of FILE; "ready" once a writer matches

   The domain is ROS_DOMAIN_ID, the configuration CYCLONEDDS_URI (read by Cyclone itself). QoS: ROS's default
   profile (reliable, volatile, keep last 10; the recorder keeps more). */

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "dds/dds.h"
#include "ros2_msgs.h"

#define WAIT_S 30
#define MAX_JOINTS 64
#define MAX_LINE 4096

static void fail(const char *what, dds_return_t rc)
{
  fprintf(stderr, "peer: %s: %s\n", what, rc < 0 ? dds_strretcode(rc) : "failed");
  exit(1);
}

static dds_entity_t participant(void)
{
  const char *id = getenv("ROS_DOMAIN_ID");
  dds_entity_t p = dds_create_participant(id ? (dds_domainid_t)atoi(id) : 0, NULL, NULL);
  if (p < 0)
    fail("participant", p);
  return p;
}

static dds_qos_t *ros_qos(int32_t depth)
{
  dds_qos_t *qos = dds_create_qos();
  dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, DDS_MSECS(100));
  dds_qset_durability(qos, DDS_DURABILITY_VOLATILE);
  dds_qset_history(qos, DDS_HISTORY_KEEP_LAST, depth);
  return qos;
}

static int publish(const char *rows, int subscribers)
{
  FILE *in = fopen(rows, "r");
  char line[MAX_LINE], *names[MAX_JOINTS], *token;
  uint32_t n = 0;
  if (in == NULL || fgets(line, sizeof line, in) == NULL)
    fail(rows, 0);
  for (token = strtok(line, " \n"); token != NULL && n < MAX_JOINTS; token = strtok(NULL, " \n"))
    names[n++] = strdup(token);
  dds_entity_t p = participant();
  dds_entity_t topic = dds_create_topic(p, &sensor_msgs_msg_dds__JointState__desc, "rt/joint_states", NULL, NULL);
  dds_qos_t *qos = ros_qos(10);
  dds_entity_t writer = dds_create_writer(p, topic, qos, NULL);
  dds_delete_qos(qos);
  if (writer < 0)
    fail("writer", writer);
  dds_publication_matched_status_t matched;
  dds_time_t deadline = dds_time() + DDS_SECS(WAIT_S);
  do {
    dds_get_publication_matched_status(writer, &matched);
    if (dds_time() > deadline)
      fail("no reader matched", 0);
    dds_sleepfor(DDS_MSECS(20));
  } while (matched.current_count < (uint32_t)subscribers);
  dds_sleepfor(DDS_MSECS(500)); /* the readers see this writer after it sees them */
  double position[MAX_JOINTS];
  sensor_msgs_msg_dds__JointState_ message;
  memset(&message, 0, sizeof message);
  message.header.frame_id = "base";
  message.name._length = message.name._maximum = n;
  message.name._buffer = names;
  message.position._length = message.position._maximum = n;
  message.position._buffer = position;
  long long stamp, first = -1;
  dds_time_t begin = dds_time();
  while (fscanf(in, "%lld", &stamp) == 1) {
    for (uint32_t k = 0; k < n; k++)
      if (fscanf(in, "%lf", &position[k]) != 1)
        fail("a row", 0);
    first = first < 0 ? stamp : first;
    dds_time_t due = begin + (stamp - first);
    if (due > dds_time())
      dds_sleepfor(due - dds_time());
    message.header.stamp.sec = (int32_t)(stamp / 1000000000);
    message.header.stamp.nanosec = (uint32_t)(stamp % 1000000000);
    dds_return_t rc = dds_write_ts(writer, &message, stamp);
    if (rc < 0)
      fail("write", rc);
  }
  dds_wait_for_acks(writer, DDS_SECS(10));
  dds_sleepfor(DDS_MSECS(500));
  fclose(in);
  return dds_delete(p) < 0;
}

static int record(const char *name, const char *path)
{
  char dds_name[256];
  snprintf(dds_name, sizeof dds_name, "rt/%s", name[0] == '/' ? name + 1 : name);
  FILE *out = fopen(path, "a");
  if (out == NULL)
    fail(path, 0);
  dds_entity_t p = participant();
  dds_entity_t topic = dds_create_topic(p, &std_msgs_msg_dds__String__desc, dds_name, NULL, NULL);
  dds_qos_t *qos = ros_qos(10000);
  dds_entity_t reader = dds_create_reader(p, topic, qos, NULL);
  dds_delete_qos(qos);
  if (reader < 0)
    fail("reader", reader);
  dds_subscription_matched_status_t matched = {0};
  dds_time_t deadline = dds_time() + DDS_SECS(WAIT_S);
  while (matched.current_count < 1 && dds_time() < deadline) {
    dds_sleepfor(DDS_MSECS(20));
    dds_get_subscription_matched_status(reader, &matched);
  }
  printf(matched.current_count ? "ready\n" : "no publisher\n");
  fflush(stdout);
  void *samples[64] = {NULL};
  dds_sample_info_t infos[64];
  for (;;) {
    dds_return_t taken = dds_take(reader, samples, infos, 64, 64);
    for (dds_return_t k = 0; k < taken; k++)
      if (infos[k].valid_data)
        fprintf(out, "%s\n", ((std_msgs_msg_dds__String_ *)samples[k])->data);
    if (taken > 0) {
      dds_return_loan(reader, samples, taken);
      fflush(out);
    } else {
      dds_sleepfor(DDS_MSECS(5));
    }
  }
  return 0; /* never: the test stops the recorder */
}

int main(int argc, char **argv)
{
  if (argc == 4 && strcmp(argv[1], "publish") == 0)
    return publish(argv[2], atoi(argv[3]));
  if (argc == 4 && strcmp(argv[1], "record") == 0)
    return record(argv[2], argv[3]);
  fprintf(stderr, "usage: peer publish ROWS SUBSCRIBERS | peer record TOPIC FILE\n");
  return 2;
}
