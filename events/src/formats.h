// Factories of the individual formats; the public entry points are in evkit/events/io.h.
#pragma once

#include <memory>
#include <string>

#include "evkit/events/io.h"

namespace evkit::detail {

std::unique_ptr<EventReader> openTextReader(const std::string& path);
std::unique_ptr<EventWriter> openTextWriter(const std::string& path, SensorSize sensor);

std::unique_ptr<EventReader> openHdf5Reader(const std::string& path);
std::unique_ptr<EventWriter> openHdf5Writer(const std::string& path, SensorSize sensor,
                                            const WriterOptions& options);

std::unique_ptr<EventReader> openRpgFolderReader(const std::string& path);

std::unique_ptr<EventReader> openAedat2Reader(const std::string& path);
std::unique_ptr<EventReader> openAedat31Reader(const std::string& path);
std::unique_ptr<EventReader> openAedat4Reader(const std::string& path);
std::unique_ptr<EventWriter> openAedat4Writer(const std::string& path, SensorSize sensor,
                                              const WriterOptions& options);

std::unique_ptr<EventReader> openEvt2Reader(const std::string& path);
std::unique_ptr<EventReader> openEvt3Reader(const std::string& path);
std::unique_ptr<EventReader> openDatReader(const std::string& path);
// "2.0", "3.0", or "" when the '%' header names no EVT version.
std::string propheseeRawVersion(const std::string& path);

}  // namespace evkit::detail
