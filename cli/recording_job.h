// `evkit deblur --recording FILE --frames ...` (a whole recording, resumable, shardable) and
// `evkit video DIR` (the merge). The work itself is evkit/deblur/recording_job.h's.
#pragma once

#include <string>

#include "common.h"
#include "evkit/deblur/settings.h"

namespace evkit::cli {

// The options of a recording job, added to `evkit deblur`'s.
void addRecordingJobOptions(po::options_description& opts);

// Runs the job `vm` describes (with --recording and --frames); exit code 1 when a frame failed.
int runRecordingDeblur(const po::variables_map& vm, const std::string& method,
                       MethodSettings settings);

}  // namespace evkit::cli
